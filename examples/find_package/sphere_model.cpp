// A sphere phantom through the installed libraries: write it as NRRD, read it back, build the
// gradational model, and check that the model covers exactly the tissue voxels.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>

#include "base/error.h"
#include "base/version.h"
#include "convert/phantom.h"
#include "convert/prepare.h"
#include "io/volume_io.h"
#include "model/gradational_builder.h"
#include "model/model.h"

int main(int argc, char** argv) {
  try {
    namespace fs = std::filesystem;
    const fs::path folder = argc > 1 ? fs::path(argv[1]) : fs::temp_directory_path();

    // a 32^3 sphere of 1 mm voxels, through a file as a user's volume would come
    vx::PhantomSettings settings;
    settings.name = "sphere";
    settings.size = 32;
    vx::PhantomShape shape;
    const fs::path file = folder / "sphere_model_example.nrrd";
    vx::write_volume(vx::make_phantom(settings, &shape), file);
    const vx::Volume volume = vx::read_volume(file);
    fs::remove(file);

    // HU >= -200 is tissue; the gradational model of it
    const vx::VoxelGrid grid = vx::prepare_grid(volume, vx::PrepareOptions{});
    const vx::Model model = vx::build_model(grid);

    const double voxels_mm3 = double(shape.tissue_voxels) * std::pow(settings.spacing_mm, 3);
    std::printf("voxelastic %s: sphere r %.3g mm, %lld tissue voxels, %d elements, %d nodes, model %.6g mm^3 "
                "(voxels %.6g mm^3, analytic %.6g mm^3)\n",
                vx::kVersion, shape.half_extent_mm.x(), static_cast<long long>(shape.tissue_voxels),
                model.num_elements(), model.num_nodes(), model.total_volume_mm3(), voxels_mm3, shape.volume_mm3());
    // the model covers the tissue voxels exactly (docs/model.md section 3)
    if (std::abs(model.total_volume_mm3() - voxels_mm3) > 1e-9 * voxels_mm3 || model.num_elements() <= 0) {
      std::fprintf(stderr, "sphere_model: the model's volume differs from the tissue voxels'\n");
      return 1;
    }
    return 0;
  } catch (const vx::Error& e) {
    std::fprintf(stderr, "sphere_model: %s\n", e.what());
    return 1;
  }
}
