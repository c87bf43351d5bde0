// voxelastic-probe: palpate a gradational-resolution elastic model with a joystick (or the
// keyboard and mouse) and feel the tissue through force feedback. Units: mm, s, N, kPa.
#include <fmt/core.h>
#include <CLI/CLI.hpp>

#include <malloc.h>

#include <cstdio>
#include <exception>
#include <string>

#include "base/error.h"
#include "base/version.h"
#include "physics/element_batches.h"
#include "probe_app.h"
#include "util/exit_codes.h"
#include "util/log.h"

int main(int argc, char** argv) {
  using namespace vx::probe;
  // stdout a line at a time: the app's lines (status, notes) come from several threads beside the
  // log's on stderr (the region check, the factor cache's writer); block-buffered into a file
  // shared with stderr, a line was cut where the buffer filled
  std::setvbuf(stdout, nullptr, _IOLBF, 0);
  // glibc's malloc serves a block above its threshold with mmap and returns it to the system when
  // freed; by default the threshold grows to the size of each such block freed (up to 32 MB), so
  // after the loading frees its buffers of a few MB (the surface's embedding), later blocks of
  // that size come from the heap and their memory is not given back. A fixed threshold (the
  // default's starting value) keeps them apart: the folded organ's first start peaked at 1.83
  // GB with it, 2.01-2.16 GB without (the probe's 2 GB budget; steps as fast, 8.5 against 8.9 ms)
  mallopt(M_MMAP_THRESHOLD, 128 * 1024);
  AppOptions o;
  std::string control = "rate", device = "auto", size = "1280x800", surface = "iso", shaping;

  CLI::App app{
      "voxelastic-probe: palpate an elastic tissue model with a joystick, keyboard or mouse and feel it through "
      "force feedback (units: mm, s, N, kPa).\n"
      "INPUT is a scene (.json), a volume (.vti .mha .nii .nii.gz .nrrd, DICOM folder) or a model (.vtu) with "
      "default palpation settings."};
  app.set_version_flag("--version", std::string("voxelastic-probe ") + vx::kVersion);
  app.add_option("INPUT", o.input, "scene .json, volume or model .vtu")->required();

  auto* g_auto = app.add_option_group("automation", "scripted runs (CI)");
  g_auto
      ->add_option("--virtual-joystick", o.joystick_script,
                   "play a joystick script (t_s stick axes...) through SDL virtual joysticks, in simulated time")
      ->check(CLI::ExistingFile);
  g_auto->add_flag("--exit-after-script", o.exit_after_script, "quit when the joystick script has ended");
  g_auto->add_option("--frames", o.frames, "quit after N rendered frames")->check(CLI::PositiveNumber);
  g_auto->add_option("--duration", o.duration_s, "quit at this simulated time, s")->check(CLI::PositiveNumber);
  g_auto
      ->add_option("--soak-s", o.soak_s,
                   "a soak: a random script of presses, slides, grasps and a release this long, judged at the end "
                   "(docs/robustness.md)")
      ->check(CLI::Range(15.0, 1e5));
  g_auto->add_option("--seed", o.soak_seed, "the soak script's random seed");
  g_auto->add_option("--screenshot", o.screenshot, "write the last frame to this .png");
  g_auto->add_option("--force-log", o.force_log, "record the device force of every device tick to this .csv");
  g_auto->add_flag("--headless", o.headless,
                   "no window: physics, input and force output only (needs --duration or "
                   "--exit-after-script)");
  g_auto->add_flag("-q,--quiet", o.quiet, "print only warnings and errors (on stderr)");
  bool verbose = false;
  g_auto->add_flag("-v,--verbose", verbose, "also print details (debug level)");

  auto* g_in = app.add_option_group("input", "joystick and keyboard");
  auto* opt_control = g_in->add_option("--control", control, "rate (the paper: velocity follows the tilt) or position")
                          ->check(CLI::IsMember({"rate", "position"}));
  auto* opt_speed = g_in->add_option("--speed", o.control.mapping.max_speed_mm_s, "probe speed at full tilt, mm/s")
                        ->check(CLI::PositiveNumber);
  auto* opt_range = g_in->add_option("--range", o.control.mapping.range_mm, "position control: offset at full tilt, mm")
                        ->check(CLI::PositiveNumber);
  auto* opt_deadzone =
      g_in->add_option("--deadzone", o.control.mapping.dead_zone, "stick dead zone, fraction of full tilt")
          ->check(CLI::Range(0.0, 0.9));
  g_in->add_option("--z-axis", o.control.z_axis,
                   "stick axis for the depth motion (e.g. 2 twist, 3 throttle); -1: buttons 0/1 and the hat only")
      ->check(CLI::Range(-1, 5));
  g_in->add_flag("--invert-z", o.control.invert_z_axis, "flip the depth axis");
  g_in->add_flag("!--no-joystick", o.use_joysticks, "ignore connected joysticks (keyboard and mouse only)");

  auto* g_out = app.add_option_group("force", "force output");
  g_out->add_option("--force-output", device, "auto (haptic, else rumble), haptic, rumble or none")
      ->check(CLI::IsMember({"auto", "haptic", "rumble", "none"}));
  g_out->add_option("--max-force", o.max_force_N, "force at the device's full level, N")->check(CLI::PositiveNumber);
  g_out->add_option("--device-update-rate", o.device_update_hz, "haptic/rumble commands per second at most")
      ->check(CLI::Range(1.0, 1000.0));
  g_out
      ->add_option("--force-shaping", shaping,
                   "local (the local contact model at every device tick, the physics at its own rate) or paper (the "
                   "paper's half sines); default: the scene's device block, else paper")
      ->check(CLI::IsMember({"local", "paper"}));

  auto* g_run = app.add_option_group("timing", "threads and rates");
  g_run
      ->add_option("--physics-rate", o.physics_hz,
                   "physics thread ticks per second (steps per tick follow dt); with --force-shaping local down to "
                   "10 (each tick a physics update)")
      ->check(CLI::Range(10.0, 10000.0));
  g_run->add_option("--device-rate", o.device_hz, "device thread updates per second (1000 for haptics)")
      ->check(CLI::Range(50.0, 10000.0));
  g_run->add_option("--fps", o.fps, "display frame limit")->check(CLI::Range(1.0, 240.0));
  g_run->add_option("--threads", o.threads, "physics threads (0, the default: all cores)")->check(CLI::Range(0, 256));
  g_run->add_flag("--share-cores,!--no-share-cores", o.share_cores,
                  "while the physics runs well ahead of real time, or one thread is as fast as all (a trial now and "
                  "then), it steps on one of its threads and leaves the other cores to the display; back on all of "
                  "them when it falls 50 ms behind or its steps grow slower (default: on; --no-share-cores: every "
                  "step on all --threads)");
  g_run->add_option(
      "--factor-cache", o.factor_cache,
      "where the implicit solver keeps its factors by the matrix's content, and the material's calibration by "
      "the model's, so the next start of the same organ loads instead of factoring and calibrating: a folder, or "
      "off (default: $VOXELASTIC_FACTOR_CACHE, else ~/.cache/voxelastic/factors)");
  g_run->add_flag("--background-factor,!--no-background-factor", o.background_factor,
                  "while the tissue rests at its rest shape (no tool within reach), the implicit solver is factored "
                  "on a thread of its own and the session runs meanwhile; a tool that reaches the tissue before "
                  "the solver is ready waits for it (default: on; --no-background-factor: the first physics step "
                  "factors, as the start-up)");
  g_run->add_flag("--background-surface,!--no-background-surface", o.scene.surface_in_background,
                  "a display surface neither in the cache nor small is decimated on a thread of its own while the "
                  "session runs, a coarser preview shown until it is ready (default: on; --no-background-surface: "
                  "decimated while loading, as the start-up)");
  g_run->add_option("--size", size, "window size WIDTHxHEIGHT");
  g_run->add_flag("--levels", o.show_levels, "start with the element levels view");
  g_run
      ->add_option("--display-triangles", o.scene.display_triangles,
                   "decimate the displayed surface to about this many triangles when it has more; 0: show it whole")
      ->check(CLI::NonNegativeNumber);
  // test hooks (hidden: an empty group): a physics slowed on purpose, a slow start-up
  app.add_option("--test-step-delay", o.test_step_delay_s, "extra wall time per physics step, s")
      ->check(CLI::Range(0.0, 10.0))
      ->group("");
  app.add_option("--test-startup-delay", o.test_startup_delay_s, "extra wall time on the first physics step, s")
      ->check(CLI::Range(0.0, 60.0))
      ->group("");
  app.add_option("--test-factor-delay", o.test_factor_delay_s,
                 "extra wall time on a solver factored in the background (--background-factor), s")
      ->check(CLI::Range(0.0, 60.0))
      ->group("");
  app.add_option("--test-frame-delay", o.test_frame_delay_s, "extra wall time per frame drawn in the display's turn, s")
      ->check(CLI::Range(0.0, 10.0))
      ->group("");
  // faults on purpose (nan@STEP, runaway@STEP, throw@STEP) and a stick unplugged and back
  std::vector<std::string> faults;
  app.add_option("--test-fault", faults, "inject a physics fault: nan@STEP, runaway@STEP or throw@STEP")->group("");
  app.add_option("--test-unplug", o.test_unplug_s, "unplug virtual stick 0 at this device time, s")->group("");
  app.add_option("--test-replug", o.test_replug_s, "plug virtual stick 0 back at this device time, s")->group("");
  app.add_flag("--test-lazy-contact-cache", o.lazy_contact_cache,
               "the contact solve's cache filled as the tool goes, not reserved at the start")
      ->group("");
  app.add_option("--test-rest-fraction", o.test_rest_fraction,
                 "the rest criterion's fraction of the release displacement (0: by speed alone)")
      ->group("");

  auto* g_scene = app.add_option_group("defaults", "volumes and models (scene files set these themselves)");
  g_scene->add_option("--threshold", o.scene.threshold, "tissue HU window LO[:HI] or preset (volumes)");
  g_scene->add_option("--voxel", o.scene.voxel_mm, "resample volumes to this voxel size, mm")
      ->check(CLI::NonNegativeNumber);
  g_scene->add_option("--youngs-modulus", o.scene.youngs_modulus_kpa, "tissue stiffness, kPa")
      ->check(CLI::PositiveNumber);
  g_scene
      ->add_option("--poisson-ratio", o.scene.poisson_ratio,
                   "tissue Poisson ratio in [0, 0.5): soft tissue keeps its volume, 0.45-0.49 (default 0.45); 0 "
                   "is the paper's model")
      ->check(CLI::Range(0.0, 0.4999));
  g_scene
      ->add_option("--surface-method", surface,
                   "displayed surface: iso (smoothed iso-surface in the elements) or paper (voxel surface with "
                   "the concave steps hidden, paper 3.3)")
      ->check(CLI::IsMember({"iso", "paper"}));
  g_scene->add_option("--surface", o.scene.surface, "models: the surface .vtp written with the model")
      ->check(CLI::ExistingFile);

  try {
    (void)vx::best_simd_level();  // a bad VOXELASTIC_SIMD is an error here, not in the physics thread
    app.parse(argc, argv);
    vx::log::set_level(verbose ? vx::log::Level::debug : o.quiet ? vx::log::Level::warn : vx::log::Level::info);
    o.control.mapping.mode = vx::parse_joystick_mode(control);
    o.mode_set = opt_control->count() > 0;
    o.speed_set = opt_speed->count() > 0;
    o.range_set = opt_range->count() > 0;
    o.deadzone_set = opt_deadzone->count() > 0;
    o.surface_method = vx::parse_surface_method(surface);
    o.device = parse_device_choice(device);
    for (const auto& f : faults) o.test_faults.push_back(parse_injected_fault(f));
    if (o.soak_s > 0) {
      if (!o.joystick_script.empty()) throw vx::Error("--soak-s makes its own script: leave out --virtual-joystick");
      o.exit_after_script = true;  // the script starts with the physics' first step
    }
    if (!shaping.empty()) o.force_shaping = vx::parse_force_shaping(shaping);
    const auto x = size.find('x');
    try {
      if (x == std::string::npos) throw std::invalid_argument(size);
      o.width = std::stoi(size.substr(0, x));
      o.height = std::stoi(size.substr(x + 1));
    } catch (const std::exception&) {
      throw vx::Error("--size '" + size + "': give WIDTHxHEIGHT, e.g. 1280x800");
    }
    if (o.width < 320 || o.height < 240 || o.width > 8192 || o.height > 8192)
      throw vx::Error("--size '" + size + "': between 320x240 and 8192x8192");
    return run_probe_app(o);
  } catch (const CLI::ParseError& e) {
    // --help and --version exit 0; every usage mistake exits 2, as voxelastic does
    return app.exit(e) == 0 ? vx::exit_code::ok : vx::exit_code::usage;
  } catch (const vx::Error& e) {
    fmt::print(stderr, "voxelastic-probe: error: {}\n", e.what());
    return kExitError;
  } catch (const std::exception& e) {
    fmt::print(stderr, "voxelastic-probe: internal error: {} (please report this)\n", e.what());
    return vx::exit_code::internal;
  }
}
