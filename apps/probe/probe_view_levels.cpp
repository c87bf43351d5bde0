// The probe view's elements by level (the `l` key): each element's faces as polygons of its own
// points, shrunk towards its centroid so the levels read as separate cells, cut open facing the
// viewer, coloured by level as in pictures.
#include <fmt/core.h>
#include <vtkActor.h>
#include <vtkCamera.h>
#include <vtkCellArray.h>
#include <vtkCellData.h>
#include <vtkIdTypeArray.h>
#include <vtkLookupTable.h>
#include <vtkMapper.h>
#include <vtkPlane.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataMapper.h>
#include <vtkProperty.h>
#include <vtkRenderer.h>
#include <vtkTextActor.h>
#include <vtkUnsignedCharArray.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "base/error.h"
#include "io/element_faces.h"
#include "probe_view_impl.h"
#include "render/palette.h"

namespace vx::probe {

LevelCells make_level_cells(const Model& model) {
  LevelCells cells;
  const int ne = model.num_elements();
  cells.element_offsets.reserve(std::size_t(ne) + 1);
  cells.element_offsets.push_back(0);
  cells.element_polys.push_back(0);
  FacePolygons faces;
  for (int e = 0; e < ne; ++e) {
    const int b = model.element_offsets[std::size_t(e)], n = model.num_vertices(e);
    const auto first_point = std::int32_t(cells.point_node.size());
    for (int i = 0; i < n; ++i) cells.point_node.push_back(model.element_vertices[std::size_t(b + i)]);
    cells.element_offsets.push_back(std::int32_t(cells.point_node.size()));
    faces.clear();
    if (model.is_2d()) {
      // a 2D element is one polygon: its vertex list goes round it (gradational_builder_2d.cpp)
      for (int i = 0; i < n; ++i) cells.poly_points.push_back(first_point + i);
      cells.poly_offsets.push_back(std::int32_t(cells.poly_points.size()));
      cells.poly_level.push_back(model.element_level[std::size_t(e)]);
      cells.element_polys.push_back(std::int32_t(cells.poly_level.size()));
      continue;
    }
    append_element_faces(model, e, faces);
    for (int f = 0; f < faces.size(); ++f) {
      for (int k = faces.offsets[std::size_t(f)]; k < faces.offsets[std::size_t(f) + 1]; ++k) {
        // the face's node as one of this element's points
        const std::int32_t node = faces.nodes[std::size_t(k)];
        int local = -1;
        for (int i = 0; i < n; ++i)
          if (model.element_vertices[std::size_t(b + i)] == node) local = i;
        if (local < 0) throw Error("element " + std::to_string(e) + ": a face node is not a vertex");
        cells.poly_points.push_back(first_point + local);
      }
      cells.poly_offsets.push_back(std::int32_t(cells.poly_points.size()));
      cells.poly_level.push_back(model.element_level[std::size_t(e)]);
    }
    cells.element_polys.push_back(std::int32_t(cells.poly_level.size()));
  }
  cells.levels = model.num_levels();
  cells.rest_centroids = model.rest_centroids;
  cells.rest_nodes = model.rest_positions;
  // the element edge of each level, as the model has it (one voxel in the voxel layout)
  cells.level_size_mm.assign(std::size_t(cells.levels), 0.0);
  cells.level_voxels.assign(std::size_t(cells.levels), 0);
  for (int e = 0; e < ne; ++e) {
    const auto l = std::size_t(model.element_level[std::size_t(e)]);
    cells.level_size_mm[l] = model.element_size_mm[std::size_t(e)];
    cells.level_voxels[l] = model.element_edge_voxels(e);
  }
  return cells;
}

Rgb level_rgb(int level) {
  const std::array<double, 3> c = level_colour(level);
  return Rgb{c[0], c[1], c[2]};
}

void ProbeView::Impl::build_levels() {
  if (!setup.levels) return;
  const LevelCells& c = *setup.levels;
  level_poly = make<vtkPolyData>();
  auto pts = make<vtkPoints>();
  pts->SetDataTypeToDouble();
  pts->SetNumberOfPoints(vtkIdType(c.point_node.size()));
  level_poly->SetPoints(pts);
  level_poly->SetPolys(make<vtkCellArray>());
  last_nodes = c.rest_nodes;

  auto lut = make<vtkLookupTable>();
  const int n = std::max(1, c.levels);
  lut->SetNumberOfTableValues(n);
  for (int l = 0; l < n; ++l) {
    const Rgb col = level_rgb(l);
    lut->SetTableValue(l, col.r, col.g, col.b, 1.0);
  }
  lut->SetRange(0, n - 1);
  lut->Build();
  auto mapper = make<vtkPolyDataMapper>();
  mapper->SetInputData(level_poly);
  mapper->SetLookupTable(lut);
  mapper->SetScalarModeToUseCellData();
  mapper->SetScalarRange(0, n - 1);
  mapper->SetColorModeToMapScalars();
  level_cut = make<vtkPlane>();
  level_actor = make<vtkActor>();
  level_actor->SetMapper(mapper);
  level_actor->GetProperty()->SetEdgeVisibility(true);
  level_actor->GetProperty()->SetEdgeColor(0.15, 0.15, 0.18);
  level_actor->GetProperty()->SetLineWidth(1.0);
  level_actor->GetProperty()->SetAmbient(0.25);
  level_actor->SetVisibility(false);
  renderer->AddActor(level_actor);

  for (int l = 0; l < c.levels; ++l) {
    auto t = make<vtkTextActor>();
    t->SetInput(fmt::format("level {}: elements {:g} mm ({} voxels) wide", l, c.level_size_mm[std::size_t(l)],
                            c.level_voxels[std::size_t(l)])
                    .c_str());
    set_text_style(t->GetTextProperty(), 14, level_rgb(l));
    t->SetVisibility(false);
    renderer->AddViewProp(t);
    level_legend.push_back(t);
  }
}

void ProbeView::Impl::set_levels(bool on) {
  if (on && !level_actor && !setup.levels && setup.make_levels) {
    // the first show: the cells made now (ViewSetup::make_levels)
    try {
      setup.levels = setup.make_levels();
    } catch (const std::exception& e) {
      std::fprintf(stderr, "voxelastic-probe: warning: the elements view cannot be shown: %s\n", e.what());
    }
    setup.make_levels = nullptr;  // (asked once)
    build_levels();
  }
  levels_on = on && level_actor;
  if (!level_actor) return;
  level_actor->SetVisibility(levels_on);
  for (auto& t : level_legend) t->SetVisibility(levels_on);
  // a cut-away: the near half of the tissue is removed, the elements behind it show
  vtkMapper* m = surface_actor->GetMapper();
  m->RemoveAllClippingPlanes();
  if (levels_on) {
    m->AddClippingPlane(level_cut);
    update_levels(true);
  }
}

void ProbeView::Impl::update_levels(bool force_cut) {
  const LevelCells& c = *setup.levels;
  // the cut: a vertical plane through the tissue's centre, facing the viewer; the elements
  // whose rest centroid is behind it are drawn whole (remade when the view turns)
  const Eigen::Vector3d away = view_basis_of(renderer->GetActiveCamera(), setup.world_up).col(2);
  if (force_cut || away.dot(cut_away) < std::cos(10.0 * M_PI / 180.0)) {
    cut_away = away;
    level_cut->SetOrigin(focus.data());
    level_cut->SetNormal(away.data());
    auto offsets = make<vtkIdTypeArray>();
    auto conn = make<vtkIdTypeArray>();
    auto level = make<vtkUnsignedCharArray>();
    level->SetName("level");
    offsets->InsertNextValue(0);
    const int ne = int(c.element_offsets.size()) - 1;
    for (int e = 0; e < ne; ++e) {
      if ((c.rest_centroids.col(e) - focus).dot(away) < 0) continue;
      for (int f = c.element_polys[std::size_t(e)]; f < c.element_polys[std::size_t(e) + 1]; ++f) {
        for (int k = c.poly_offsets[std::size_t(f)]; k < c.poly_offsets[std::size_t(f) + 1]; ++k)
          conn->InsertNextValue(c.poly_points[std::size_t(k)]);
        offsets->InsertNextValue(conn->GetNumberOfValues());
        level->InsertNextValue(std::uint8_t(c.poly_level[std::size_t(f)]));
      }
    }
    auto polys = make<vtkCellArray>();
    polys->SetData(offsets, conn);
    level_poly->SetPolys(polys);
    level_poly->GetCellData()->SetScalars(level);
  }
  // the points: each element shrunk towards its centroid so the levels read as separate cells
  vtkPoints* lp = level_poly->GetPoints();
  auto* out = static_cast<double*>(lp->GetVoidPointer(0));
  const int ne = int(c.element_offsets.size()) - 1;
  for (int e = 0; e < ne; ++e) {
    const int b = c.element_offsets[std::size_t(e)], n = c.element_offsets[std::size_t(e) + 1] - b;
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (int i = 0; i < n; ++i) centroid += last_nodes.col(c.point_node[std::size_t(b + i)]);
    centroid /= double(std::max(1, n));
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector3d p = centroid + 0.9 * (last_nodes.col(c.point_node[std::size_t(b + i)]) - centroid);
      std::copy_n(p.data(), 3, out + 3 * (b + i));
    }
  }
  lp->Modified();
  level_poly->Modified();
}

void ProbeView::toggle_levels() { impl_->set_levels(!impl_->levels_on); }

bool ProbeView::shows_levels() const { return impl_->levels_on; }

}  // namespace vx::probe
