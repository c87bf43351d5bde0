// Seed corpora for the fuzz targets, made from the project's phantoms and samples:
//   voxelastic_fuzz_seeds SAMPLES_DIR OUT_DIR
// writes OUT_DIR/<target>/ for every target of fuzz/CMakeLists.txt: small phantoms in every
// volume format (NIfTI plain and gzip, int16 and float), DICOM series in every transfer syntax
// the writer offers (one file each for fuzz_dicom_file, whole series for fuzz_dicom_series),
// the sample scenes and joystick scripts.
#include <cstdio>
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "base/error.h"
#include "convert/phantom.h"
#include "io/dicom_series.h"
#include "io/volume_io.h"
#include "util/log.h"

namespace fs = std::filesystem;

namespace {

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void put(const fs::path& p, const std::string& bytes) {
  fs::create_directories(p.parent_path());
  std::ofstream(p, std::ios::binary) << bytes;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: %s SAMPLES_DIR OUT_DIR\n", argv[0]);
    return 2;
  }
  const fs::path samples = argv[1], out = argv[2];
  vx::log::set_level(vx::log::Level::warn);
  try {
    const fs::path tmp = out / ".work";
    fs::remove_all(tmp);
    fs::create_directories(tmp);
    // volumes: small phantoms, integral (int16 files) and with noise (float files)
    int n = 0;
    for (const char* name : {"sphere", "block-lesion", "torus"})
      for (const double noise : {0.0, 3.5}) {
        vx::PhantomSettings s;
        s.name = name;
        s.size = 8 + 2 * (n % 2);
        s.spacing_mm = 0.75 + 0.5 * (n % 3);
        s.noise_hu = noise;
        const vx::Volume v = vx::make_phantom(s);
        const std::string stem = std::string(name) + (noise > 0 ? "-noisy" : "");
        for (const auto& [target, ext] : std::vector<std::pair<std::string, std::string>>{
                 {"fuzz_vti", ".vti"}, {"fuzz_mha", ".mha"}, {"fuzz_nrrd", ".nrrd"}}) {
          vx::write_volume(v, tmp / (stem + ext));
          put(out / target / (stem + ext), slurp(tmp / (stem + ext)));
        }
        // fuzz_nifti: first byte 0 = plain .nii follows, 1 = the .nii to gzip follows
        vx::write_volume(v, tmp / (stem + ".nii"));
        const std::string nii = slurp(tmp / (stem + ".nii"));
        put(out / "fuzz_nifti" / (stem + ".nii"), std::string(1, '\0') + nii);
        put(out / "fuzz_nifti" / (stem + ".nii.gz"), std::string(1, '\1') + nii);
        ++n;
      }
    // DICOM: an 8 x 8 x 3 series per transfer syntax
    vx::PhantomSettings s;
    s.name = "block-lesion";
    s.size = 8;
    const vx::Volume v = vx::make_phantom(s);
    for (const char* syntax : {"explicit-little", "implicit-little", "rle", "jpeg-lossless", "jpeg-ls-lossless",
                               "jpeg2000-lossless", "jpeg2000"}) {
      vx::Volume thin = v;
      thin.geometry.dims.z() = 3;
      thin.hu.resize(std::size_t(thin.geometry.voxel_count()));
      const fs::path dir = tmp / syntax;
      vx::write_dicom_series(thin, dir, {.transfer_syntax = syntax});
      std::string series;
      int k = 0;
      std::vector<fs::path> files;
      for (const auto& e : fs::directory_iterator(dir)) files.push_back(e.path());
      std::sort(files.begin(), files.end());
      for (const auto& f : files) {
        const std::string bytes = slurp(f);
        if (k == 0) put(out / "fuzz_dicom_file" / (std::string(syntax) + ".dcm"), bytes);
        series += (k++ ? "\n--voxelastic-fuzz-file--\n" : "") + bytes;
      }
      put(out / "fuzz_dicom_series" / (std::string(syntax) + ".series"), series);
    }
    // scenes and joystick scripts
    for (const auto& e : fs::directory_iterator(samples / "scenes")) {
      const std::string ext = e.path().extension().string();
      if (ext == ".json") put(out / "fuzz_scene" / e.path().filename(), slurp(e.path()));
      if (ext == ".joy") put(out / "fuzz_joystick_script" / e.path().filename(), slurp(e.path()));
    }
    put(out / "fuzz_joystick_script" / "two-sticks.joy",
        "sticks 2\n0 0 0 0 0\n0.5 1 0.2 -0.4 1 0 b01\n1.0 0 -1 1 0 0.5 b10000001\n");
    fs::remove_all(tmp);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "voxelastic_fuzz_seeds: %s\n", e.what());
    return 1;
  }
  return 0;
}
