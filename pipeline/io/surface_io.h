#pragma once
/// @file surface_io.h
/// Saving and loading an embedded surface as VTK XML polydata (.vtp), in LPS mm, so 3D Slicer
/// and ParaView show it in place and a simulation can deform it after loading.
///
/// File layout: points = rest vertices (double), polys = triangles (counter-clockwise from
/// outside), point data `Normals` (rest vertex normals, the active normals) and `embed_count`
/// (embedding entries per vertex, for inspection); field data `voxelastic` =
/// "voxelastic-surface", `format_version`, `surface_method` (paper, iso, staircase),
/// `model_nodes` (node count of the model), and the embedding as CSR: `embed_offsets`
/// (vertices + 1), `embed_nodes` (model node ids), `embed_weights` (doubles).

#include <filesystem>

#include "model/model.h"
#include "surface/surface.h"

class vtkPolyData;

namespace vx {

/// Writes the surface atomically (a .vtp path); throws vx::Error on failure.
void save_surface(const EmbeddedSurface& surface, const std::filesystem::path& path);
/// Writes any polydata as VTK XML (.vtp: appended, zlib, 64-bit ids), all or nothing (temporary
/// file, then renamed). Throws vx::Error.
void save_polydata(vtkPolyData& polydata, const std::filesystem::path& path);

/// Loads a surface written by save_surface; throws vx::Error (what is wrong) for other files.
/// With `model`, also checks that the surface belongs to it: same node count, and the
/// embedding applied to the model's rest positions gives the stored rest vertices
/// (within 1e-6 mm), so a surface of another model with the same node count is refused.
[[nodiscard]] EmbeddedSurface load_surface(const std::filesystem::path& path, const Model* model = nullptr);

}  // namespace vx
