#include "convert/iso_surface.h"

#include <vtkCellArray.h>
#include <vtkDiscreteFlyingEdges3D.h>
#include <vtkFloatArray.h>
#include <vtkFlyingEdges3D.h>
#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPolyData.h>
#include <vtkSmartPointer.h>
#include <vtkUnsignedCharArray.h>
#include <vtkWindowedSincPolyDataFilter.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "base/error.h"
#include "util/vtk_messages.h"

namespace vx {

namespace {

/// Maps grid voxel indices to the volume's: the volume must have the grid's spacing and
/// direction, and the grid's voxels must sit on the volume's voxels (a crop), so the offset is
/// whole voxels. Returns false otherwise.
bool voxel_offset(const GridGeometry& grid, const GridGeometry& volume, Eigen::Vector3i& offset) {
  if (!grid.spacing_mm.isApprox(volume.spacing_mm, 1e-9) || !grid.direction.isApprox(volume.direction, 1e-9))
    return false;
  const Eigen::Vector3d o = volume.lps_to_index(grid.origin_mm);
  for (int i = 0; i < 3; ++i) {
    offset[i] = int(std::lround(o[i]));
    if (std::abs(o[i] - offset[i]) > 1e-4) return false;
  }
  return true;
}

/// The iso-surface of `image` (scaled index space, grid `geo`) at `value`: flying edges
/// (discrete: the boundary of the label `value`), windowed-sinc smoothing, in LPS mm, oriented
/// outward. Throws vx::Error when VTK fails.
TriangleMesh contour_image(vtkImageData* image, bool discrete, double value, const IsoSurfaceSettings& settings,
                           const GridGeometry& geo) {
  // each filter watched on its own, not through VTK's global output window: this may run on a
  // thread beside a window's rendering (the probe app's display surface, decimate_surface.h)
  vtkNew<VtkFilterWatch> vtk_messages;
  vtkSmartPointer<vtkPolyData> contour;
  if (!discrete) {
    vtkNew<vtkFlyingEdges3D> fe;
    vtk_messages->watch(fe);
    fe->SetInputData(image);
    fe->SetValue(0, value);
    fe->ComputeNormalsOff();
    fe->ComputeGradientsOff();
    fe->ComputeScalarsOff();
    fe->Update();
    contour = fe->GetOutput();
  } else {
    vtkNew<vtkDiscreteFlyingEdges3D> fe;
    vtk_messages->watch(fe);
    fe->SetInputData(image);
    fe->SetValue(0, value);
    fe->ComputeNormalsOff();
    fe->ComputeGradientsOff();
    fe->ComputeScalarsOff();
    fe->Update();
    contour = fe->GetOutput();
  }
  vtkSmartPointer<vtkPolyData> smooth = contour;
  if (settings.smoothing_iterations > 0) {
    // windowed sinc: a low-pass filter on the vertex positions that barely shrinks the shape
    vtkNew<vtkWindowedSincPolyDataFilter> ws;
    vtk_messages->watch(ws);
    ws->SetInputData(contour);
    ws->SetNumberOfIterations(settings.smoothing_iterations);
    ws->SetPassBand(settings.pass_band);
    ws->BoundarySmoothingOff();
    ws->FeatureEdgeSmoothingOff();
    ws->NonManifoldSmoothingOn();
    ws->NormalizeCoordinatesOn();
    ws->Update();
    smooth = ws->GetOutput();
  }
  if (!vtk_messages->errors.empty())
    throw Error("VTK could not make the iso-surface: " + vtk_messages->first_error("unknown error"));

  TriangleMesh mesh;
  const vtkIdType np = smooth->GetNumberOfPoints();
  mesh.vertices_mm.resize(3, np);
  for (vtkIdType i = 0; i < np; ++i) {
    double p[3];
    smooth->GetPoint(i, p);
    mesh.vertices_mm.col(i) = geo.origin_mm + geo.direction * Eigen::Vector3d(p[0], p[1], p[2]);
  }
  std::vector<Eigen::Vector3i> tris;
  vtkCellArray* polys = smooth->GetPolys();
  tris.reserve(std::size_t(polys->GetNumberOfCells()));
  polys->InitTraversal();
  vtkIdType npts = 0;
  const vtkIdType* pts = nullptr;
  while (polys->GetNextCell(npts, pts)) {
    // flying edges makes triangles; fan anything else, drop triangles repeating a vertex
    for (vtkIdType t = 1; t + 1 < npts; ++t) {
      const Eigen::Vector3i tri{static_cast<int>(pts[0]), static_cast<int>(pts[t]), static_cast<int>(pts[t + 1])};
      if (tri[0] != tri[1] && tri[1] != tri[2] && tri[2] != tri[0]) tris.push_back(tri);
    }
  }
  mesh.triangles.resize(3, Eigen::Index(tris.size()));
  for (std::size_t t = 0; t < tris.size(); ++t) mesh.triangles.col(Eigen::Index(t)) = tris[t];
  // outward: the enclosed volume is positive
  if (enclosed_volume_mm3(mesh.vertices_mm, mesh.triangles) < 0) mesh.triangles.row(1).swap(mesh.triangles.row(2));
  return mesh;
}

}  // namespace

TriangleMesh extract_iso_surface(const VoxelGrid& grid, const Volume* hu, const IsoSurfaceSettings& settings) {
  const GridGeometry& geo = grid.geometry();
  Eigen::Vector3i lo, hi;
  grid.tissue_bounds(lo, hi);
  if ((hi.array() <= lo.array()).any()) throw Error("cannot make an iso-surface: the voxel grid holds no tissue");
  const bool use_hu = hu != nullptr && std::isfinite(settings.iso_hu);
  Eigen::Vector3i hu_offset = Eigen::Vector3i::Zero();
  if (use_hu) {
    if (std::int64_t(hu->hu.size()) != hu->geometry.voxel_count())
      throw Error("cannot make an iso-surface: the HU volume holds " + std::to_string(hu->hu.size()) + " values for " +
                  std::to_string(hu->geometry.voxel_count()) + " voxels");
    if (!voxel_offset(geo, hu->geometry, hu_offset))
      throw Error(
          "cannot make an iso-surface from HU values: the volume was resampled for the model (its voxels "
          "differ from the model's); use the binary iso-surface (no HU iso value) or keep the voxel size");
  }
  if (settings.smoothing_iterations < 0 || !(settings.pass_band > 0 && settings.pass_band <= 2))
    throw Error("iso-surface smoothing: iterations must be >= 0 and the pass band in (0, 2]");

  // the tissue box plus two voxels of outside on each side, so the surface is closed
  const Eigen::Vector3i start = lo.array() - 2;
  const Eigen::Vector3i n = (hi - lo).array() + 4;
  vtkNew<vtkImageData> image;
  image->SetDimensions(n.x(), n.y(), n.z());
  image->SetSpacing(geo.spacing_mm.x(), geo.spacing_mm.y(), geo.spacing_mm.z());
  // in "scaled index" space: point = spacing * (i, j, k); LPS = origin + direction * point
  image->SetOrigin(geo.spacing_mm.x() * start.x(), geo.spacing_mm.y() * start.y(), geo.spacing_mm.z() * start.z());
  if (use_hu) {
    // HU values place the surface between voxel centres; the grid decides which side each
    // voxel is on (tissue kept at or above the iso value, the rest below), so the surface has
    // the topology of what the model holds
    const float iso = float(settings.iso_hu);
    const float above = std::nextafter(iso, INFINITY), below = std::nextafter(iso, -INFINITY);
    image->AllocateScalars(VTK_FLOAT, 1);
    auto* out = static_cast<float*>(image->GetScalarPointer());
    const Eigen::Vector3i& vd = hu->geometry.dims;
    for (int k = 0; k < n.z(); ++k)
      for (int j = 0; j < n.y(); ++j)
        for (int i = 0; i < n.x(); ++i) {
          const Eigen::Vector3i v = start + Eigen::Vector3i(i, j, k), w = v + hu_offset;
          const bool in_volume = (w.array() >= 0).all() && (w.array() < vd.array()).all();
          float x = in_volume ? hu->at(w.x(), w.y(), w.z()) : below;
          if (!std::isfinite(x)) x = below;
          x = grid.at(v.x(), v.y(), v.z()) ? std::max(x, above) : std::min(x, below);
          out[i + std::size_t(n.x()) * (j + std::size_t(n.y()) * k)] = x;
        }
  } else {
    image->AllocateScalars(VTK_UNSIGNED_CHAR, 1);
    auto* out = static_cast<unsigned char*>(image->GetScalarPointer());
    for (int k = 0; k < n.z(); ++k)
      for (int j = 0; j < n.y(); ++j)
        for (int i = 0; i < n.x(); ++i) {
          const Eigen::Vector3i v = start + Eigen::Vector3i(i, j, k);
          out[i + std::size_t(n.x()) * (j + std::size_t(n.y()) * k)] = grid.at(v.x(), v.y(), v.z());
        }
  }

  return contour_image(image, !use_hu, use_hu ? settings.iso_hu : 1.0, settings, geo);
}

TriangleMesh extract_coarse_iso_surface(const VoxelGrid& grid, int factor, const IsoSurfaceSettings& settings) {
  if (factor < 1) throw Error("coarse iso-surface: the factor must be >= 1");
  const GridGeometry& geo = grid.geometry();
  Eigen::Vector3i lo, hi;
  grid.tissue_bounds(lo, hi);
  if ((hi.array() <= lo.array()).any()) throw Error("cannot make an iso-surface: the voxel grid holds no tissue");
  if (settings.smoothing_iterations < 0 || !(settings.pass_band > 0 && settings.pass_band <= 2))
    throw Error("iso-surface smoothing: iterations must be >= 0 and the pass band in (0, 2]");
  // blocks of factor^3 voxels from the tissue box's low corner, one block of outside around
  const Eigen::Vector3i blocks = ((hi - lo).array() + factor - 1) / factor;
  const Eigen::Vector3i n = blocks.array() + 2;
  vtkNew<vtkImageData> image;
  image->SetDimensions(n.x(), n.y(), n.z());
  const Eigen::Vector3d h = double(factor) * geo.spacing_mm;
  image->SetSpacing(h.x(), h.y(), h.z());
  // block b's centre in voxel index space: lo + factor * b + (factor - 1) / 2 (b from -1)
  const Eigen::Vector3d first =
      (lo.cast<double>().array() - double(factor) + 0.5 * (factor - 1)).matrix().cwiseProduct(geo.spacing_mm);
  image->SetOrigin(first.x(), first.y(), first.z());
  image->AllocateScalars(VTK_FLOAT, 1);
  auto* out = static_cast<float*>(image->GetScalarPointer());
  std::fill(out, out + std::size_t(n.x()) * std::size_t(n.y()) * std::size_t(n.z()), 0.0f);
  const float share = 1.0f / float(factor * factor * factor);
  for (int k = lo.z(); k < hi.z(); ++k)
    for (int j = lo.y(); j < hi.y(); ++j)
      for (int i = lo.x(); i < hi.x(); ++i)
        if (grid.at(i, j, k)) {
          const Eigen::Vector3i b = (Eigen::Vector3i(i, j, k) - lo) / factor + Eigen::Vector3i::Ones();
          out[std::size_t(b.x()) +
              std::size_t(n.x()) * (std::size_t(b.y()) + std::size_t(n.y()) * std::size_t(b.z()))] += share;
        }
  // the half-full level of the blocks' tissue fraction: a surface near the voxels' own
  return contour_image(image, false, 0.5, settings, geo);
}

EmbeddedSurface make_surface(const Model& model, const VoxelGrid& grid, const Volume* hu, SurfaceMethod method,
                             const IsoSurfaceSettings& settings) {
  // a 2D (slice) model's surface is the slice itself, a flat sheet (surface.h)
  if (model.is_2d()) return make_slice_surface(model);
  if (grid.dims() != model.grid.dims || grid.count() != model.covered_voxels())
    throw Error("cannot make the surface: the voxel grid is not the one the model was built from");
  switch (method) {
    case SurfaceMethod::staircase: return make_voxel_surface(model, grid, false);
    case SurfaceMethod::paper: return make_voxel_surface(model, grid, true);
    case SurfaceMethod::slice: return make_slice_surface(model);
    case SurfaceMethod::iso: {
      const TriangleMesh mesh = extract_iso_surface(grid, hu, settings);
      return embed_surface(model, mesh.vertices_mm, mesh.triangles, SurfaceMethod::iso);
    }
  }
  throw Error("unknown surface method");
}

}  // namespace vx
