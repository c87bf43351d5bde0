#include "convert/decimate_surface.h"

#include <fmt/core.h>
#include <vtkCellArray.h>
#include <vtkDecimatePro.h>
#include <vtkGenericCell.h>
#include <vtkIdTypeArray.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkQuadricClustering.h>
#include <vtkQuadricDecimation.h>
#include <vtkSmartPointer.h>
#include <vtkStaticCellLocator.h>
#include <vtkStaticPointLocator.h>
#include <Eigen/Geometry>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>
#include <vector>

#include "base/error.h"
#include "convert/iso_surface.h"
#include "io/surface_cache.h"
#include "util/vtk_messages.h"

namespace vx {

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

vtkSmartPointer<vtkPolyData> to_poly(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles) {
  auto poly = vtkSmartPointer<vtkPolyData>::New();
  vtkNew<vtkPoints> pts;
  pts->SetDataTypeToDouble();
  pts->SetNumberOfPoints(vertices.cols());
  std::copy_n(vertices.data(), 3 * vertices.cols(), static_cast<double*>(pts->GetVoidPointer(0)));
  poly->SetPoints(pts);
  vtkNew<vtkIdTypeArray> offsets, conn;
  const vtkIdType nt = triangles.cols();
  offsets->SetNumberOfValues(nt + 1);
  conn->SetNumberOfValues(3 * nt);
  for (vtkIdType t = 0; t <= nt; ++t) offsets->SetValue(t, 3 * t);
  for (vtkIdType i = 0; i < 3 * nt; ++i) conn->SetValue(i, triangles.data()[i]);
  vtkNew<vtkCellArray> polys;
  polys->SetData(offsets, conn);
  poly->SetPolys(polys);
  return poly;
}

bool cancelled(const DecimationSettings& s) { return s.cancel && s.cancel->load(std::memory_order_relaxed); }

/// Whether decimate_surface keeps `full` as it is.
bool kept_whole(const Model& model, const EmbeddedSurface& full, const DecimationSettings& settings) {
  if (settings.target_triangles < 0) throw Error("display surface: the target triangle count must be >= 0");
  if (full.model_nodes != model.num_nodes())
    throw Error(fmt::format("display surface: the surface is embedded in a model of {} nodes, this one has {}",
                            full.model_nodes, model.num_nodes()));
  return settings.target_triangles == 0 || full.num_triangles() <= settings.target_triangles ||
         full.method == SurfaceMethod::slice || model.is_2d();
}

/// `full` restricted to the vertices `source` (ids into `full`) and `triangles` over them, each
/// vertex with its embedding row of `full`.
EmbeddedSurface sub_surface(const EmbeddedSurface& full, const std::vector<std::int32_t>& source,
                            Eigen::Matrix3Xd vertices, Eigen::Matrix3Xi triangles) {
  EmbeddedSurface s;
  s.method = full.method;
  s.model_nodes = full.model_nodes;
  s.rest_vertices = std::move(vertices);
  s.triangles = std::move(triangles);
  s.embed_offsets.assign(1, 0);
  for (const std::int32_t f : source) {
    const auto b = full.embed_offsets[std::size_t(f)], e = full.embed_offsets[std::size_t(f) + 1];
    s.embed_nodes.insert(s.embed_nodes.end(), full.embed_nodes.begin() + b, full.embed_nodes.begin() + e);
    s.embed_weights.insert(s.embed_weights.end(), full.embed_weights.begin() + b, full.embed_weights.begin() + e);
    s.embed_offsets.push_back(std::int32_t(s.embed_nodes.size()));
  }
  s.finalize();
  return s;
}

}  // namespace

std::string DecimationReport::summary() const {
  if (preview && preview_blocks > 0)
    return fmt::format(
        "display surface: a coarse preview of {} triangles ({} vertices; {}) in {:.2f} s, for the "
        "about {} of the full surface, whose decimation, in the background, replaces it",
        triangles_after, vertices_after, method, build_s + decimate_s + embed_s, triangles_before);
  if (preview)
    return fmt::format(
        "display surface: a preview of {} triangles ({} vertices, {}) of the {} in {:.2f} s, shown "
        "until the decimation, in the background, replaces it",
        triangles_after, vertices_after, method, triangles_before, decimate_s + embed_s);
  if (!decimated && !from_cache) return fmt::format("display surface: {} triangles (not decimated)", triangles_before);
  if (from_cache)
    return fmt::format("display surface {} -> {} triangles ({} -> {} vertices): loaded from the cache in {:.2f} s",
                       triangles_before, triangles_after, vertices_before, vertices_after, cache_s);
  return fmt::format(
      "display surface decimated {} -> {} triangles ({} -> {} vertices; {}) in {:.2f} s; embedding: {} "
      "({:.2f} s)",
      triangles_before, triangles_after, vertices_before, vertices_after, method, decimate_s, embedding, embed_s);
}

EmbeddedSurface decimate_surface(const Model& model, const EmbeddedSurface& full, const DecimationSettings& settings,
                                 DecimationReport* report_out, SurfaceCache* cache) {
  DecimationReport report;
  report.triangles_before = report.triangles_after = full.num_triangles();
  report.vertices_before = report.vertices_after = full.num_vertices();
  if (kept_whole(model, full, settings)) {
    if (report_out) *report_out = report;
    return full;
  }

  std::optional<SurfaceKey> key;
  if (cache) {
    const auto tc = std::chrono::steady_clock::now();
    ContentHash h = surface_key_hash(model, settings.target_triangles, settings.feature_angle_deg);
    h.add_value(std::uint8_t(1));  // decimated from this full surface
    add_surface_content(h, full);
    key = SurfaceKey{h.value(), model.num_nodes(), settings.target_triangles};
    if (std::optional<CachedSurface> kept = cache->load(*key)) {
      report.decimated = report.from_cache = true;
      report.triangles_after = kept->surface.num_triangles();
      report.vertices_after = kept->surface.num_vertices();
      report.cache_s = seconds_since(tc);
      if (report_out) *report_out = report;
      return std::move(kept->surface);
    }
  }

  // the rest surface, each point carrying its vertex id in the full surface
  const auto t0 = std::chrono::steady_clock::now();
  vtkSmartPointer<vtkPolyData> input = to_poly(full.rest_vertices, full.triangles);
  {
    vtkNew<vtkIdTypeArray> ids;
    ids->SetName("vx_full_vertex");
    ids->SetNumberOfValues(full.num_vertices());
    for (vtkIdType v = 0; v < full.num_vertices(); ++v) ids->SetValue(v, v);
    input->GetPointData()->AddArray(ids);
  }
  const double reduction = 1.0 - double(settings.target_triangles) / double(full.num_triangles());
  // topology-preserving vertex removal first (vertices stay where they were, on the full
  // surface); should it stop short of the target, quadric edge collapses instead
  // each filter watched on its own (not VTK's global output window: this may run on a thread
  // beside a window's rendering), and stopped when the caller cancels
  vtkNew<VtkFilterWatch> watch;
  vtkNew<vtkDecimatePro> pro;
  watch->watch(pro, settings.cancel);
  pro->SetInputData(input);
  pro->SetTargetReduction(reduction);
  pro->PreserveTopologyOn();
  pro->SplittingOff();
  pro->BoundaryVertexDeletionOff();
  pro->SetFeatureAngle(settings.feature_angle_deg);
  pro->SetMaximumError(VTK_DOUBLE_MAX);
  pro->Update();
  vtkPolyDataAlgorithm* decimate = pro;
  report.method = "vtkDecimatePro, topology preserved";
  vtkNew<vtkQuadricDecimation> quadric;
  if (cancelled(settings)) throw DecimationCancelled();
  if (pro->GetOutput()->GetNumberOfPolys() > vtkIdType(1.1 * settings.target_triangles)) {
    watch->watch(quadric, settings.cancel);
    quadric->SetInputData(input);
    quadric->SetTargetReduction(reduction);
    quadric->VolumePreservationOn();  // Lindstrom-Turk volume constraint: no shrinking
    quadric->AttributeErrorMetricOff();
    quadric->Update();
    decimate = quadric;
    report.method = "vtkQuadricDecimation";
  }
  if (watch->cancelled || cancelled(settings)) throw DecimationCancelled();
  vtkPolyData* out = decimate->GetOutput();
  if (!watch->errors.empty() || !out || out->GetNumberOfPolys() == 0)
    throw Error("VTK could not decimate the display surface: " + watch->first_error("no triangles left"));

  // the triangles (dropping any that repeat a vertex) and the vertices they use, renumbered
  const vtkIdType np = out->GetNumberOfPoints();
  std::vector<int> new_id(std::size_t(np), -1);
  std::vector<Eigen::Vector3i> tris;
  tris.reserve(std::size_t(out->GetNumberOfPolys()));
  vtkCellArray* polys = out->GetPolys();
  polys->InitTraversal();
  vtkIdType npts = 0;
  const vtkIdType* pts = nullptr;
  int used = 0;
  while (polys->GetNextCell(npts, pts)) {
    for (vtkIdType t = 1; t + 1 < npts; ++t) {
      const vtkIdType a = pts[0], b = pts[t], c = pts[t + 1];
      if (a == b || b == c || c == a) continue;
      Eigen::Vector3i tri;
      const vtkIdType corner[3] = {a, b, c};
      for (int k = 0; k < 3; ++k) {
        int& id = new_id[std::size_t(corner[k])];
        if (id < 0) id = used++;
        tri[k] = id;
      }
      tris.push_back(tri);
    }
  }
  Eigen::Matrix3Xd vertices(3, used);
  // the full surface's vertex each kept point was, when it is one (vertex removal keeps points)
  auto* ids = vtkIdTypeArray::SafeDownCast(out->GetPointData()->GetArray("vx_full_vertex"));
  std::vector<std::int32_t> source(std::size_t(used), -1);
  for (vtkIdType p = 0; p < np; ++p) {
    if (new_id[std::size_t(p)] < 0) continue;
    double x[3];
    out->GetPoint(p, x);
    const int v = new_id[std::size_t(p)];
    vertices.col(v) = Eigen::Vector3d(x[0], x[1], x[2]);
    if (ids && ids->GetNumberOfValues() == np) {
      const vtkIdType f = ids->GetValue(p);
      if (f >= 0 && f < full.num_vertices() && full.rest_vertices.col(f) == vertices.col(v))
        source[std::size_t(v)] = int(f);
    }
  }
  const bool all_kept = std::none_of(source.begin(), source.end(), [](std::int32_t f) { return f < 0; });
  Eigen::Matrix3Xi triangles(3, Eigen::Index(tris.size()));
  for (std::size_t t = 0; t < tris.size(); ++t) triangles.col(Eigen::Index(t)) = tris[t];
  // edge collapses keep the orientation; keep it outward should VTK ever flip the mesh
  if ((enclosed_volume_mm3(vertices, triangles) < 0) != (enclosed_volume_mm3(full.rest_vertices, full.triangles) < 0))
    triangles.row(1).swap(triangles.row(2));
  report.decimate_s = seconds_since(t0);

  const auto t1 = std::chrono::steady_clock::now();
  EmbeddedSurface s;
  if (all_kept) {
    // every vertex is one of the full surface's: its embedding row as it is (no new weights)
    s = sub_surface(full, source, std::move(vertices), std::move(triangles));
    report.embedding = "the full surface's";
  } else {
    // moved vertices: the embedding the iso-surface uses (trilinear in the voxel cell over
    // lattice points, each a node or an element's affine fit)
    s = embed_surface(model, vertices, triangles, full.method);
    report.embedding = "embed_surface";
  }
  report.embed_s = seconds_since(t1);
  report.decimated = true;
  report.triangles_after = s.num_triangles();
  report.vertices_after = s.num_vertices();
  if (cache && key)
    cache->store(*key, CachedSurface{s, full.num_triangles(), full.num_vertices()}, report.decimate_s + report.embed_s);
  if (report_out) *report_out = report;
  return s;
}

namespace {

/// display_surface_of_grid's key: the model, the grid, the method, the iso-surface and
/// decimation settings (and, through surface_key_hash, the VTK version).
SurfaceKey grid_surface_key(const Model& model, const VoxelGrid& grid, SurfaceMethod method,
                            const DecimationSettings& settings, const IsoSurfaceSettings& iso) {
  ContentHash h = surface_key_hash(model, settings.target_triangles, settings.feature_angle_deg);
  h.add_value(std::uint8_t(2));  // built from this grid by make_surface, then decimated
  const GridGeometry& g = grid.geometry();
  h.add(g.dims.data(), sizeof(int) * 3);
  h.add(g.spacing_mm.data(), sizeof(double) * 3);
  h.add(g.origin_mm.data(), sizeof(double) * 3);
  h.add(g.direction.data(), sizeof(double) * 9);
  h.add_value(std::uint64_t(grid.data().size()));
  if (!grid.data().empty()) h.add(grid.data().data(), grid.data().size());
  h.add_value(std::int32_t(method));
  h.add_value(iso.iso_hu);
  h.add_value(std::int32_t(iso.smoothing_iterations));
  h.add_value(iso.pass_band);
  return SurfaceKey{h.value(), model.num_nodes(), settings.target_triangles};
}

/// The display surface of `key` from `cache`, with its report; nothing when it is not there.
std::optional<EmbeddedSurface> cached_display_surface(SurfaceCache& cache, const SurfaceKey& key,
                                                      std::chrono::steady_clock::time_point t0,
                                                      DecimationReport* report_out) {
  std::optional<CachedSurface> kept = cache.load(key);
  if (!kept) return std::nullopt;
  DecimationReport report;
  report.from_cache = true;
  report.triangles_before = int(kept->source_triangles);
  report.vertices_before = int(kept->source_vertices);
  report.triangles_after = kept->surface.num_triangles();
  report.vertices_after = kept->surface.num_vertices();
  report.decimated = report.triangles_after != report.triangles_before;
  report.cache_s = seconds_since(t0);
  if (report_out) *report_out = report;
  return std::move(kept->surface);
}

/// The full surface decimated (decimate_surface) and offered to `cache` under `key`.
EmbeddedSurface decimate_and_keep(const Model& model, const EmbeddedSurface& full, double build_s,
                                  const DecimationSettings& settings, DecimationReport* report_out, SurfaceCache* cache,
                                  const std::optional<SurfaceKey>& key) {
  DecimationReport report;
  EmbeddedSurface shown = decimate_surface(model, full, settings, &report);
  report.build_s = build_s;
  if (cache && key)
    cache->store(*key, CachedSurface{shown, full.num_triangles(), full.num_vertices()},
                 build_s + report.decimate_s + report.embed_s);
  if (report_out) *report_out = report;
  return shown;
}

/// Faces between a tissue voxel and a voxel that is not (the grid's border counts as outside).
std::int64_t tissue_faces(const VoxelGrid& grid) {
  Eigen::Vector3i lo, hi;
  grid.tissue_bounds(lo, hi);
  std::int64_t faces = 0;
  for (int k = lo.z(); k < hi.z(); ++k)
    for (int j = lo.y(); j < hi.y(); ++j)
      for (int i = lo.x(); i < hi.x(); ++i)
        if (grid.at(i, j, k))
          faces += !grid.at(i - 1, j, k) + !grid.at(i + 1, j, k) + !grid.at(i, j - 1, k) + !grid.at(i, j + 1, k) +
                   !grid.at(i, j, k - 1) + !grid.at(i, j, k + 1);
  return faces;
}

/// stage_display_surface_of_grid's preview of a large iso-surface: extract_coarse_iso_surface on
/// blocks of `blocks` voxels, embedded in `model`, clustered to the target when above 1.5 times it
/// (the blocks give about estimate / blocks^2 triangles, between 1 and (1 + 1/blocks)^2 times the
/// target: a clustering of 0.3 s on the folded organ, not worth it for 1.3 times).
/// The report's decimate_s and embed_s are the contour's and the embedding's (with the
/// clustering's); the caller sets build_s and triangles_before.
EmbeddedSurface coarse_preview(const Model& model, const VoxelGrid& grid, int blocks,
                               const DecimationSettings& settings, const IsoSurfaceSettings& iso,
                               DecimationReport* report_out) {
  DecimationReport report;
  auto t = std::chrono::steady_clock::now();
  const TriangleMesh mesh = extract_coarse_iso_surface(grid, blocks, iso);
  report.decimate_s = seconds_since(t);
  t = std::chrono::steady_clock::now();
  EmbeddedSurface shown = embed_surface(model, mesh.vertices_mm, mesh.triangles, SurfaceMethod::iso);
  report.embed_s = seconds_since(t);
  report.method = fmt::format("the voxels on blocks of {0} x {0} x {0}", blocks);
  if (shown.num_triangles() > 1.5 * settings.target_triangles) {
    DecimationReport clustered;
    shown = preview_surface(model, shown, settings, &clustered);
    report.decimate_s += clustered.decimate_s;
    report.embed_s += clustered.embed_s;
    report.method += ", then " + clustered.method;
  }
  report.triangles_after = shown.num_triangles();
  report.vertices_after = shown.num_vertices();
  report.preview = true;
  report.preview_blocks = blocks;
  *report_out = report;
  return shown;
}

}  // namespace

EmbeddedSurface display_surface_of_grid(const Model& model, const VoxelGrid& grid, SurfaceMethod method,
                                        const DecimationSettings& settings, DecimationReport* report_out,
                                        SurfaceCache* cache, const IsoSurfaceSettings& iso) {
  std::optional<SurfaceKey> key;
  const auto t0 = std::chrono::steady_clock::now();
  if (cache) {
    key = grid_surface_key(model, grid, method, settings, iso);
    if (std::optional<EmbeddedSurface> kept = cached_display_surface(*cache, *key, t0, report_out))
      return *std::move(kept);
  }
  const EmbeddedSurface full = make_surface(model, grid, nullptr, method, iso);
  return decimate_and_keep(model, full, seconds_since(t0), settings, report_out, cache, key);
}

StagedDisplaySurface stage_display_surface_of_grid(std::shared_ptr<const Model> model, const VoxelGrid& grid,
                                                   SurfaceMethod method, const DecimationSettings& settings,
                                                   std::shared_ptr<SurfaceCache> cache, const IsoSurfaceSettings& iso) {
  if (!model) throw Error("display surface: no model");
  StagedDisplaySurface staged;
  std::optional<SurfaceKey> key;
  const auto t0 = std::chrono::steady_clock::now();
  if (cache) {
    key = grid_surface_key(*model, grid, method, settings, iso);
    if (std::optional<EmbeddedSurface> kept = cached_display_surface(*cache, *key, t0, &staged.report)) {
      staged.shown = *std::move(kept);
      return staged;
    }
  }
  const std::int64_t estimate = method == SurfaceMethod::iso && !model->is_2d() ? 2 * tissue_faces(grid) : 0;
  const int target = settings.target_triangles;
  bool coarse = false;
  if (target > 0 && estimate > 4 * std::int64_t(target)) {
    // a large surface: a preview from the voxels on coarser blocks, not the full surface
    const int blocks = int(std::sqrt(double(estimate) / double(target)));
    try {
      staged.shown = coarse_preview(*model, grid, blocks, settings, iso, &staged.report);
      // tissue thinner than half a block (a sheet) leaves little or nothing at the half level:
      // then the preview clustered from the full surface, as for a smaller one
      coarse = double(staged.shown.num_triangles()) >= 0.25 * double(estimate) / double(blocks * blocks);
    } catch (const Error&) {
      coarse = false;  // VTK failed on the blocks: the same
    }
    if (coarse) {
      staged.report.triangles_before = int(std::min<std::int64_t>(estimate, std::numeric_limits<int>::max()));
      staged.report.build_s = seconds_since(t0) - staged.report.decimate_s - staged.report.embed_s;
    } else {
      staged.report = DecimationReport{};
    }
  }
  if (!coarse) {
    EmbeddedSurface full = make_surface(*model, grid, nullptr, method, iso);
    const double build_s = seconds_since(t0);
    if (kept_whole(*model, full, settings)) {
      staged.shown = decimate_and_keep(*model, full, build_s, settings, &staged.report, cache.get(), key);
      return staged;
    }
    try {
      staged.shown = preview_surface(*model, full, settings, &staged.report);
    } catch (const Error&) {
      // no preview (VTK left no triangles: a target of a few triangles): decimated now, as
      // display_surface_of_grid does
      staged.shown = decimate_and_keep(*model, full, build_s, settings, &staged.report, cache.get(), key);
      return staged;
    }
    staged.report.build_s = build_s;
  }
  // the full surface is built again when the decimation runs, not kept meanwhile: 80 MB on the
  // folded organ (its embedding), which would otherwise sit on top of the factorisation's peak
  // (make_surface gives the same surface each time: SurfaceCacheTest)
  auto kept_grid = std::make_shared<const VoxelGrid>(grid);
  staged.finish = [model, kept_grid, method, iso, settings, cache, key](DecimationReport* report) {
    if (cancelled(settings)) throw DecimationCancelled();  // the iso-surface itself cannot be stopped
    const auto t = std::chrono::steady_clock::now();
    const EmbeddedSurface again = make_surface(*model, *kept_grid, nullptr, method, iso);
    return decimate_and_keep(*model, again, seconds_since(t), settings, report, cache.get(), key);
  };
  return staged;
}

EmbeddedSurface preview_surface(const Model& model, const EmbeddedSurface& full, const DecimationSettings& settings,
                                DecimationReport* report_out) {
  DecimationReport report;
  report.triangles_before = report.triangles_after = full.num_triangles();
  report.vertices_before = report.vertices_after = full.num_vertices();
  if (kept_whole(model, full, settings)) {
    if (report_out) *report_out = report;
    return full;
  }
  const auto t0 = std::chrono::steady_clock::now();
  vtkSmartPointer<vtkPolyData> input = to_poly(full.rest_vertices, full.triangles);
  // bins of side h: a closed surface of area A crosses about c A / h^2 of them (c about 1.5 to
  // 2), each a vertex with about two triangles; so h from A and the target, then once more
  // from the count the first try gave
  double area = 0.0;
  for (Eigen::Index t = 0; t < full.triangles.cols(); ++t) {
    const Eigen::Vector3d a = full.rest_vertices.col(full.triangles(0, t));
    area += 0.5 * (full.rest_vertices.col(full.triangles(1, t)) - a)
                      .cross(full.rest_vertices.col(full.triangles(2, t)) - a)
                      .norm();
  }
  const double target = double(settings.target_triangles);
  double h = std::sqrt(3.5 * area / target);
  vtkNew<VtkFilterWatch> watch;
  vtkNew<vtkQuadricClustering> cluster;
  watch->watch(cluster, nullptr);
  cluster->SetInputData(input);
  cluster->AutoAdjustNumberOfDivisionsOff();
  cluster->UseInputPointsOn();  // each bin's vertex one of the input's: its embedding row kept
  cluster->CopyCellDataOff();
  const auto run = [&] {
    double b[6];
    input->GetBounds(b);
    // at most 2,048 bins along an axis (a bin of 0.1 mm over 20 cm)
    const auto divisions = [&](int axis) {
      return int(std::clamp(std::ceil((b[2 * axis + 1] - b[2 * axis]) / h) + 1.0, 1.0, 2048.0));
    };
    cluster->SetNumberOfDivisions(divisions(0), divisions(1), divisions(2));
    cluster->Update();
    return double(cluster->GetOutput()->GetNumberOfPolys());
  };
  const double first = run();
  if (first > 1.15 * target || first < 0.7 * target) {
    h *= first > 0 ? std::sqrt(first / target) : 0.5;  // none left: bins of half the size
    (void)run();
  }
  vtkPolyData* out = cluster->GetOutput();
  if (!watch->errors.empty() || !out || out->GetNumberOfPolys() == 0)
    throw Error("VTK could not cluster the display surface's preview: " + watch->first_error("no triangles left"));
  // the output's points are input points: find each one's id in `full` (nearest point, at
  // distance 0 up to the output's float precision)
  vtkNew<vtkStaticPointLocator> locator;
  locator->SetDataSet(input);
  locator->BuildLocator();
  const vtkIdType np = out->GetNumberOfPoints();
  std::vector<std::int32_t> full_id(std::size_t(np), -1);  // per output point, found once
  std::vector<int> new_id(std::size_t(np), -1);            // per output point, once a kept triangle uses it
  std::vector<Eigen::Vector3i> tris;
  tris.reserve(std::size_t(out->GetNumberOfPolys()));
  std::vector<std::int32_t> source;  // per preview vertex: its vertex of `full`
  vtkCellArray* polys = out->GetPolys();
  polys->InitTraversal();
  vtkIdType npts = 0;
  const vtkIdType* pts = nullptr;
  while (polys->GetNextCell(npts, pts)) {
    if (npts != 3) continue;
    std::int32_t f[3];
    for (int k = 0; k < 3; ++k) {
      std::int32_t& id = full_id[std::size_t(pts[k])];
      if (id < 0) {
        double x[3];
        out->GetPoint(pts[k], x);
        const vtkIdType found = locator->FindClosestPoint(x);
        if (found < 0) throw Error("display surface preview: a clustered point has no input point");
        id = std::int32_t(found);
      }
      f[k] = id;
    }
    if (f[0] == f[1] || f[1] == f[2] || f[2] == f[0]) continue;  // degenerate: its points stay out
    Eigen::Vector3i tri;
    for (int k = 0; k < 3; ++k) {
      int& id = new_id[std::size_t(pts[k])];
      if (id < 0) {
        id = int(source.size());
        source.push_back(f[k]);
      }
      tri[k] = id;
    }
    tris.push_back(tri);
  }
  Eigen::Matrix3Xd vertices(3, Eigen::Index(source.size()));
  for (std::size_t v = 0; v < source.size(); ++v) vertices.col(Eigen::Index(v)) = full.rest_vertices.col(source[v]);
  Eigen::Matrix3Xi triangles(3, Eigen::Index(tris.size()));
  for (std::size_t t = 0; t < tris.size(); ++t) triangles.col(Eigen::Index(t)) = tris[t];
  report.decimate_s = seconds_since(t0);
  const auto t1 = std::chrono::steady_clock::now();
  EmbeddedSurface s = sub_surface(full, source, std::move(vertices), std::move(triangles));
  report.embed_s = seconds_since(t1);
  report.preview = true;
  report.method = fmt::format("vtkQuadricClustering, bins of {:.2f} mm", h);
  report.embedding = "the full surface's";
  report.triangles_after = s.num_triangles();
  report.vertices_after = s.num_vertices();
  if (report_out) *report_out = report;
  return s;
}

MeshDistance mesh_distance_mm(const Eigen::Matrix3Xd& a_vertices, const Eigen::Matrix3Xi& a_triangles,
                              const Eigen::Matrix3Xd& b_vertices, const Eigen::Matrix3Xi& b_triangles) {
  if (a_triangles.cols() == 0 || b_triangles.cols() == 0) throw Error("mesh distance: a mesh has no triangles");
  MeshDistance d;
  double sum = 0.0;
  // the largest and summed distance of the vertices of `from` to the triangles of `to`
  const auto one_way = [&sum](const Eigen::Matrix3Xd& from, const Eigen::Matrix3Xd& to_v,
                              const Eigen::Matrix3Xi& to_t) {
    vtkSmartPointer<vtkPolyData> to = to_poly(to_v, to_t);
    vtkNew<vtkStaticCellLocator> locator;
    locator->SetDataSet(to);
    locator->BuildLocator();
    vtkNew<vtkGenericCell> cell;
    double worst = 0.0;
    for (Eigen::Index v = 0; v < from.cols(); ++v) {
      double p[3] = {from(0, v), from(1, v), from(2, v)}, closest[3], d2 = 0.0;
      vtkIdType cell_id = -1;
      int sub_id = 0;
      locator->FindClosestPoint(p, closest, cell, cell_id, sub_id, d2);
      const double dist = std::sqrt(d2);
      worst = std::max(worst, dist);
      sum += dist;
    }
    return worst;
  };
  d.max_a_to_b_mm = one_way(a_vertices, b_vertices, b_triangles);
  d.max_b_to_a_mm = one_way(b_vertices, a_vertices, a_triangles);
  d.max_mm = std::max(d.max_a_to_b_mm, d.max_b_to_a_mm);
  d.mean_mm = sum / double(a_vertices.cols() + b_vertices.cols());
  return d;
}

}  // namespace vx
