// `voxelastic-probe --soak-s 60` on a small folded organ (the folded phantom at 4.3 mm voxels:
// 1,964 elements, 12,079 nodes, full solves: under 20,000 nodes the app runs no regional
// solves; the app's default material, Poisson 0.45 since issue 27, so the local contact models
// use the patch compliance and its memory is judged with the rest): random presses and slides
// for a minute, then a release. What the issue asks of a long session, in its CI size
// (docs/robustness.md, "Soak"; the 10-minute run on the 1 mm folded organ is a documented
// command). With regional solves (a larger organ) the tissue does not come back within 1 %
// (nodes left outside the region sleep where the tool left them): the doc says so.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <regex>
#include <string>

#include "support/run_binary.h"

namespace fs = std::filesystem;

namespace {

const fs::path kVoxelastic = fs::path(VX_BINARY_DIR) / "apps" / "voxelastic" / "voxelastic";
const fs::path kProbe = fs::path(VX_BINARY_DIR) / "apps" / "probe" / "voxelastic-probe";

TEST(ProbeSoak, AMinuteOfRandomPalpationOnAFoldedOrganStaysFiniteFlatAndRealTime) {
  const fs::path dir = fs::temp_directory_path() / ("vx_probe_soak_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const fs::path organ = dir / "folded.nrrd";
  const auto made =
      vx::testing::run_binary(kVoxelastic, "phantom folded --size 50 --spacing 4.3 -o folded.nrrd", dir, dir);
  ASSERT_EQ(made.code, 0) << made.out << made.err;
  const auto r =
      // the physics slowed to about 0.6x real time, as an organ of 1 mm voxels runs in the app
      // (0.3x): the script's rest is wall time, the tissue's rest must be simulated time
      vx::testing::run_binary(
          kProbe, "folded.nrrd --headless --force-shaping local --soak-s 60 --seed 1 --test-step-delay 0.02", dir, dir);
  fs::remove_all(dir);
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  // the figures in the test's log, passed or failed (the device line: its longest tick, its priority)
  std::smatch device;
  const bool has_device = std::regex_search(r.out, device, std::regex(R"(device: \d+ ticks .*)"));
  if (has_device) std::printf("%s\n", device.str().c_str());
  const std::regex line(
      R"(soak: 60 s, seed 1: non-finite (\d+) .*resident memory ([0-9.]+) MB after the warm-up \(at ([0-9.]+) s\), ([0-9.]+) MB at the end \(([-+0-9.]+) %; the contact solve's bounded cache ([0-9.]+) -> ([0-9.]+) MB, reserved at the start, the rest [-+0-9.]+ %\); device forces per second at least ([0-9.]+) over (\d+) one-second windows \(the hypervisor's steal: ([0-9]+) ms of CPU in that second, at most ([0-9]+) ms in one; short beyond the ticks the steal can take: at most ([0-9]+) forces in a second\); tissue at the end ([0-9.]+) mm from its rest \(([^)]*)\), ([0-9.]+) % of its largest displacement ([0-9.]+) mm; energy guard (\d+) ticks)");
  std::smatch m;
  ASSERT_TRUE(std::regex_search(r.out, m, line)) << r.out;
  std::printf("%s\n", m.str().c_str());
  EXPECT_EQ(std::stoi(m[1]), 0) << "non-finite values";
  EXPECT_GT(std::stod(m[2]), 50.0) << "the organ's memory was measured";
  // resident memory growth after the warm-up: 0.97-1.0 MB (0.75-0.77 %) in quiet runs, 1.35 MB
  // (1.05 %) once in a clean-clone CI run (the threads' allocator arenas and pages touched late);
  // 3 MB catches a leak of 1.4 kB or more per physics step (the minute makes about 2,100 steps)
  EXPECT_LT(std::abs(std::stod(m[4]) - std::stod(m[2])), 3.0) << "resident memory growth after the warm-up, MB";
  EXPECT_LT(std::abs(std::stod(m[5])), 2.5) << "resident memory growth after the warm-up, %";
  // the contact solve's cache is reserved when the solver is set up: it does not grow after
  EXPECT_GT(std::stod(m[6]), 0.0) << "the contact cache's size, MB";
  EXPECT_EQ(m[6].str(), m[7].str()) << "the contact cache after the warm-up and at the end, MB";
  // the issue's aim is 950 in every second; on this shared 2-core machine the worst second read
  // 974-997 when it was quiet and 937-948 under a load of 8-10 (other builds), so CI holds it to
  // 900 (a device thread starved for 100 ms in one second). The test runs alone (RUN_SERIAL), but
  // in a virtual machine the whole guest stops now and then: for up to 4 ms in a quiet minute,
  // 10-22 ms under the hypervisor's load, and a loaded host took 260-970 ms of CPU in a second
  // (docs/probe.md, "The device thread's late seconds"). No thread of the guest runs then, ours
  // or not, so the bar is held to the forces missing beyond what the steal can take (one per
  // tick of steal, summed over the CPUs): 100 in a second. On bare metal the steal reads 0 and
  // this is 900 forces in every second.
  EXPECT_LE(std::stod(m[12]), 100.0) << "device forces missing in a second beyond the hypervisor's steal (the worst "
                                     << "second: " << m[8] << " forces, " << m[10] << " ms of steal in it); "
                                     << (has_device ? device.str() : "no device line");
  EXPECT_LE(std::stoi(m[10]), std::stoi(m[11])) << "the worst second's steal is at most the largest of any second, ms";
  EXPECT_GE(std::stoi(m[9]), 55) << "one-second windows";
  EXPECT_GT(std::stod(m[16]), 1.0) << "the presses deformed the tissue, mm";
  EXPECT_LT(std::stod(m[15]), 1.0) << "the tissue back at rest after the release, % of its largest displacement";
  // the energy guard is reported (a count; it may act)
  EXPECT_GE(std::stoi(m[17]), 0);
  // after the script the session went on until the tissue slept or had its idle window (10 s
  // simulated since the release; the script's 8 s of wall time gave it about 5)
  const std::regex settle(
      R"(the rest went on ([0-9.]+) s more \(([0-9.]+) s simulated; ([0-9.]+) s simulated since the release\) until (the tissue asleep|its idle window since the release over))");
  ASSERT_TRUE(std::regex_search(r.out, m, settle)) << r.out;
  EXPECT_GT(std::stod(m[1]), 0.5) << "the physics at 0.6x needed more than the script's rest, s of wall time";
  if (m[4].str() != "the tissue asleep") {
    EXPECT_GE(std::stod(m[3]), 10.5) << "simulated since the release, s";
  }
}

}  // namespace
