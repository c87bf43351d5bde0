#pragma once
/// @file model_io.h
/// Saving and loading the elastic model as VTK XML unstructured grid (.vtu), in LPS mm:
/// one VTK_POLYHEDRON cell per element (its point list is the element's vertex list, in
/// order), cell data `level`, `cell_voxels`, `cells_mask`, `anchor`, `volume_mm3`; point
/// data `lattice`, `surface`; field data for the grid geometry, the resolution and `dimensions`
/// (2: a slice model, whose elements are VTK_POLYGON cells going round each element
/// counter-clockwise seen from the slice normal, on the slice's plane in LPS mm; files without
/// it are volume models).

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "model/model.h"

namespace vx {

/// More per-element values for the file's cell data, each named with its unit
/// (`youngs_modulus_kpa`, `mean_hu`): one value per element. load_model ignores them.
using ElementArrays = std::vector<std::pair<std::string, std::vector<double>>>;

/// Writes the model atomically, with `element_arrays` as more cell data; throws vx::Error on
/// failure (an array whose length is not the element count included).
void save_model(const Model& model, const std::filesystem::path& path, const ElementArrays& element_arrays = {});

/// Loads a model written by save_model; throws vx::Error (what is missing) for other files.
[[nodiscard]] Model load_model(const std::filesystem::path& path);

}  // namespace vx
