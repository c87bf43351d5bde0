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

#include "model/model.h"

namespace vx {

/// Writes the model atomically; throws vx::Error on failure.
void save_model(const Model& model, const std::filesystem::path& path);

/// Loads a model written by save_model; throws vx::Error (what is missing) for other files.
[[nodiscard]] Model load_model(const std::filesystem::path& path);

}  // namespace vx
