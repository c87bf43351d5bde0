// The probe view's scene: the deforming tissue surface (Gouraud shading with the surface's own
// normals, tinted deeper red where it is displaced), the probes (their shapes, lit up in
// contact) and the workspace walls with the table under the tissue.
#include <fmt/format.h>
#include <vtkActor.h>
#include <vtkAppendPolyData.h>
#include <vtkAxesActor.h>
#include <vtkBillboardTextActor3D.h>
#include <vtkCamera.h>
#include <vtkCapsuleSource.h>
#include <vtkCaptionActor2D.h>
#include <vtkCellArray.h>
#include <vtkCubeSource.h>
#include <vtkCylinderSource.h>
#include <vtkDoubleArray.h>
#include <vtkIdTypeArray.h>
#include <vtkOutlineSource.h>
#include <vtkPlaneSource.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataMapper.h>
#include <vtkProperty.h>
#include <vtkRenderWindow.h>
#include <vtkRenderer.h>
#include <vtkSphereSource.h>
#include <vtkTextActor.h>
#include <vtkTextProperty.h>
#include <vtkTransform.h>
#include <vtkTransformPolyDataFilter.h>
#include <vtkUnsignedCharArray.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

#include "probe_view_impl.h"
#include "surface/surface.h"

namespace vx::probe {
namespace {

// the polydata of a probe's shape, in its own frame (tip / centre at the origin)
Ptr<vtkPolyData> probe_shape(const ProbeGeometry& g, double scene_size) {
  Ptr<vtkPolyData> out;
  const Eigen::Vector3d axis = g.axis.norm() > 0 ? Eigen::Vector3d(g.axis.normalized()) : Eigen::Vector3d(0, 0, 1);
  // VTK's sources are along +y; rotate +y onto the axis
  const Eigen::Quaterniond q = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d(0, 1, 0), axis);
  const Eigen::AngleAxisd aa(q);
  auto transform = make<vtkTransform>();
  switch (g.shape) {
    case ProbeShape::sphere: {
      auto s = make<vtkSphereSource>();
      s->SetRadius(g.radius_mm);
      s->SetThetaResolution(48);
      s->SetPhiResolution(32);
      s->Update();
      return s->GetOutput();
    }
    case ProbeShape::cylinder: {
      auto c = make<vtkCylinderSource>();
      c->SetRadius(g.radius_mm);
      c->SetHeight(std::max(g.length_mm, 1e-3));
      c->SetResolution(48);
      c->Update();
      out = c->GetOutput();
      break;
    }
    case ProbeShape::capsule: {
      // the tip sphere's centre is the probe position; the rod runs length_mm along the axis
      auto c = make<vtkCapsuleSource>();
      c->SetRadius(g.radius_mm);
      c->SetCylinderLength(std::max(g.length_mm, 1e-3));
      c->SetCenter(0.0, 0.5 * g.length_mm, 0.0);
      c->SetThetaResolution(48);
      c->SetPhiResolution(24);
      c->Update();
      out = c->GetOutput();
      break;
    }
    case ProbeShape::plane: {
      // a square plate of the scene's size, its normal along the axis, surface at the origin
      auto p = make<vtkCubeSource>();
      const double half = 0.5 * scene_size;
      p->SetBounds(-half, half, -0.04 * scene_size, 0.0, -half, half);
      p->Update();
      out = p->GetOutput();
      break;
    }
  }
  transform->RotateWXYZ(aa.angle() * 180.0 / M_PI, aa.axis().x(), aa.axis().y(), aa.axis().z());
  auto tf = make<vtkTransformPolyDataFilter>();
  tf->SetInputData(out);
  tf->SetTransform(transform);
  tf->Update();
  return tf->GetOutput();
}

}  // namespace

Eigen::Matrix3Xd vertex_normals(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles) {
  // the surface's own normals (the mean of the unit normals of the triangles around a vertex)
  EmbeddedSurface s;
  s.rest_vertices = vertices;
  s.triangles = triangles;
  s.finalize();
  return std::move(s.rest_normals);
}

void ProbeView::Impl::set_tissue_mesh() {
  // the rest surface's points, normals, triangles and tint (points and normals replaced every
  // frame; all of it again when the physics swaps the surface: replace_surface)
  const auto nv = setup.surface_vertices.cols();
  auto pts = make<vtkPoints>();
  pts->SetDataTypeToDouble();
  pts->SetNumberOfPoints(nv);
  std::copy_n(setup.surface_vertices.data(), 3 * nv, static_cast<double*>(pts->GetVoidPointer(0)));
  surface->SetPoints(pts);
  // the rest normals until the physics sends its first frame: with zero normals only the
  // ambient term lights the tissue (12 %: a large organ whose start-up takes seconds was drawn
  // almost black until its first step)
  auto normals = make<vtkDoubleArray>();
  normals->SetName("Normals");
  normals->SetNumberOfComponents(3);
  normals->SetNumberOfTuples(nv);
  const Eigen::Matrix3Xd rest_normals = vertex_normals(setup.surface_vertices, setup.surface_triangles);
  std::copy_n(rest_normals.data(), 3 * nv, normals->GetPointer(0));
  surface->GetPointData()->SetNormals(normals);
  auto offsets = make<vtkIdTypeArray>();
  auto conn = make<vtkIdTypeArray>();
  const auto nt = setup.surface_triangles.cols();
  offsets->SetNumberOfValues(nt + 1);
  conn->SetNumberOfValues(3 * nt);
  for (vtkIdType t = 0; t <= nt; ++t) offsets->SetValue(t, 3 * t);
  for (vtkIdType i = 0; i < 3 * nt; ++i) conn->SetValue(i, setup.surface_triangles.data()[i]);
  auto tris = make<vtkCellArray>();
  tris->SetData(offsets, conn);
  surface->SetPolys(tris);
  // the displacement tint: per-vertex colours, the tissue colour deepening where it is pressed
  tint = make<vtkUnsignedCharArray>();
  tint->SetName("tint");
  tint->SetNumberOfComponents(3);
  tint->SetNumberOfTuples(nv);
  for (vtkIdType i = 0; i < nv; ++i)
    tint->SetTypedTuple(i, std::array<unsigned char, 3>{static_cast<unsigned char>(255 * kTissue.r),
                                                        static_cast<unsigned char>(255 * kTissue.g),
                                                        static_cast<unsigned char>(255 * kTissue.b)}
                               .data());
  surface->GetPointData()->SetScalars(tint);
  surface->Modified();
}

void ProbeView::Impl::build_tissue() {
  surface = make<vtkPolyData>();
  set_tissue_mesh();
  auto surface_mapper = make<vtkPolyDataMapper>();
  surface_mapper->SetInputData(surface);
  surface_mapper->SetColorModeToDirectScalars();
  surface_mapper->SetScalarModeToUsePointData();
  surface_mapper->ScalarVisibilityOn();
  surface_actor = make<vtkActor>();
  surface_actor->SetMapper(surface_mapper);
  {
    vtkProperty* p = surface_actor->GetProperty();
    p->SetInterpolationToGouraud();
    p->SetColor(kTissue.r, kTissue.g, kTissue.b);
    p->SetAmbient(0.12);
    p->SetDiffuse(0.85);
    p->SetSpecular(0.25);
    p->SetSpecularPower(25.0);
    p->SetSpecularColor(1.0, 0.95, 0.9);
  }
  renderer->AddActor(surface_actor);
}

void ProbeView::Impl::build_probes() {
  for (std::size_t p = 0; p < setup.probes.size(); ++p) {
    auto mapper = make<vtkPolyDataMapper>();
    mapper->SetInputData(probe_shape(setup.probes[p], 2.0 * radius));
    auto actor = make<vtkActor>();
    actor->SetMapper(mapper);
    vtkProperty* prop = actor->GetProperty();
    prop->SetInterpolationToGouraud();
    prop->SetColor(kTool.r, kTool.g, kTool.b);
    prop->SetAmbient(0.15);
    prop->SetDiffuse(0.6);
    prop->SetSpecular(0.8);
    prop->SetSpecularPower(60.0);
    if (setup.probes[p].shape == ProbeShape::plane) prop->SetOpacity(0.5);
    const Eigen::Vector3d s = p < setup.probe_start_mm.size() ? setup.probe_start_mm[p] : Eigen::Vector3d::Zero();
    actor->SetPosition(s.x(), s.y(), s.z());
    renderer->AddActor(actor);
    probe_actors.push_back(actor);
  }
}

void ProbeView::Impl::build_walls() {
  if (!setup.walls || !setup.workspace.valid()) return;
  const Box& b = setup.workspace;
  auto outline = make<vtkOutlineSource>();
  outline->SetBounds(b.lo.x(), b.hi.x(), b.lo.y(), b.hi.y(), b.lo.z(), b.hi.z());
  auto om = make<vtkPolyDataMapper>();
  om->SetInputConnection(outline->GetOutputPort());
  auto oa = make<vtkActor>();
  oa->SetMapper(om);
  oa->GetProperty()->SetColor(0.65, 0.70, 0.78);
  oa->GetProperty()->SetLineWidth(1.5);
  oa->GetProperty()->LightingOff();
  renderer->AddActor(oa);
  wall_actors.push_back(oa);
  // the floor: the wall at the bottom (against "up"), drawn as a dark table top
  const Eigen::Vector3d up = setup.world_up.normalized();
  int axis = 0;
  up.cwiseAbs().maxCoeff(&axis);
  const double at = up[axis] > 0 ? b.lo[axis] : b.hi[axis];
  Eigen::Vector3d o = b.lo, p1 = b.lo, p2 = b.lo;
  const int u = (axis + 1) % 3, w = (axis + 2) % 3;
  o[axis] = p1[axis] = p2[axis] = at;
  p1[u] = b.hi[u];
  p2[w] = b.hi[w];
  auto floor = make<vtkPlaneSource>();
  floor->SetOrigin(o.data());
  floor->SetPoint1(p1.data());
  floor->SetPoint2(p2.data());
  auto fm = make<vtkPolyDataMapper>();
  fm->SetInputConnection(floor->GetOutputPort());
  auto fa = make<vtkActor>();
  fa->SetMapper(fm);
  fa->GetProperty()->SetColor(0.32, 0.36, 0.42);
  fa->GetProperty()->SetAmbient(0.3);
  fa->GetProperty()->SetDiffuse(0.6);
  fa->GetProperty()->SetSpecular(0.05);
  renderer->AddActor(fa);
  wall_actors.push_back(fa);
}

void ProbeView::Impl::update_tissue(const Eigen::Matrix3Xd& surface_vertices, const Eigen::Matrix3Xd& surface_normals) {
  // the tissue surface: new points and normals, same triangles
  vtkPoints* pts = surface->GetPoints();
  if (surface_vertices.cols() == pts->GetNumberOfPoints()) {
    std::copy_n(surface_vertices.data(), 3 * surface_vertices.cols(), static_cast<double*>(pts->GetVoidPointer(0)));
    pts->Modified();
  }
  auto* normals = vtkDoubleArray::SafeDownCast(surface->GetPointData()->GetNormals());
  if (normals && surface_normals.cols() == normals->GetNumberOfTuples()) {
    std::copy_n(surface_normals.data(), 3 * surface_normals.cols(), normals->GetPointer(0));
    normals->Modified();
  }
  if (tint_on && surface_vertices.cols() == setup.surface_vertices.cols()) {
    // deeper, darker red with the displacement from rest (smoothstep up to tint_full_mm)
    const Rgb deep{0.62, 0.20, 0.22};
    auto* c = tint->GetPointer(0);
    for (Eigen::Index i = 0; i < surface_vertices.cols(); ++i) {
      const double d = (surface_vertices.col(i) - setup.surface_vertices.col(i)).norm() / tint_full_mm;
      const double t0 = std::clamp(d, 0.0, 1.0), t = t0 * t0 * (3.0 - 2.0 * t0);
      c[3 * i + 0] = static_cast<unsigned char>(255.0 * (kTissue.r + t * (deep.r - kTissue.r)));
      c[3 * i + 1] = static_cast<unsigned char>(255.0 * (kTissue.g + t * (deep.g - kTissue.g)));
      c[3 * i + 2] = static_cast<unsigned char>(255.0 * (kTissue.b + t * (deep.b - kTissue.b)));
    }
    tint->Modified();
  }
  surface->Modified();
}

void ProbeView::Impl::update_probes(const std::vector<Eigen::Vector3d>& probe_positions,
                                    const std::vector<int>& probe_contacts) {
  // the probes; a probe in contact lights up
  for (std::size_t p = 0; p < probe_actors.size() && p < probe_positions.size(); ++p) {
    const Eigen::Vector3d& x = probe_positions[p];
    probe_actors[p]->SetPosition(x.x(), x.y(), x.z());
    const bool touching = p < probe_contacts.size() && probe_contacts[p] > 0;
    const Rgb& c = touching ? kToolContact : kTool;
    probe_actors[p]->GetProperty()->SetColor(c.r, c.g, c.b);
  }
}

void ProbeView::Impl::build_guides() {
  // the scale bar: a round length (1, 2 or 5 times a power of ten) about a third of the tissue's
  // width, lying along the screen's "right" at the foot of the tissue, just in front of it; a
  // bar in the scene stays true under perspective and when the camera turns
  const Eigen::Matrix3d basis = start_view_basis(setup.world_up);  // right, up, away
  const Eigen::Matrix3Xd local = basis.transpose() * setup.surface_vertices;
  const Eigen::Vector3d lo = local.rowwise().minCoeff(), hi = local.rowwise().maxCoeff();
  const double target = std::max(1e-3, 0.3 * (hi.x() - lo.x()));
  const double p10 = std::pow(10.0, std::floor(std::log10(target)));
  scale_bar_mm = p10;
  for (double m : {5.0, 2.0, 1.0})
    if (m * p10 <= target) {
      scale_bar_mm = m * p10;
      break;
    }
  // a bar 8 % of its length thick, raised a little above the table so that neither hides the other
  const double thick = std::max(0.3, 0.08 * scale_bar_mm), gap = std::max(1.0, 0.08 * (hi - lo).maxCoeff());
  const Eigen::Vector3d start =
      basis * Eigen::Vector3d(lo.x(), lo.y() + 0.5 * thick + 0.1 * thick, lo.z() - gap - thick);
  const Eigen::Vector3d right = basis.col(0), up = basis.col(1), away = basis.col(2);
  auto box = [&](const Eigen::Vector3d& centre, double along, double high) {
    auto cube = make<vtkCubeSource>();
    cube->SetXLength(along);
    cube->SetYLength(high);
    cube->SetZLength(thick);
    auto t = make<vtkTransform>();
    const double m[16] = {right.x(), up.x(), away.x(), centre.x(), right.y(), up.y(), away.y(), centre.y(),
                          right.z(), up.z(), away.z(), centre.z(), 0,         0,      0,        1};
    t->SetMatrix(m);
    auto f = make<vtkTransformPolyDataFilter>();
    f->SetInputConnection(cube->GetOutputPort());
    f->SetTransform(t);
    return f;
  };
  auto append = make<vtkAppendPolyData>();
  append->AddInputConnection(box(start + 0.5 * scale_bar_mm * right, scale_bar_mm, thick)->GetOutputPort());
  for (double end : {0.0, scale_bar_mm})  // end ticks
    append->AddInputConnection(box(start + end * right + 1.0 * thick * up, 0.6 * thick, 3 * thick)->GetOutputPort());
  auto mapper = make<vtkPolyDataMapper>();
  mapper->SetInputConnection(append->GetOutputPort());
  scale_bar = make<vtkActor>();
  scale_bar->SetMapper(mapper);
  scale_bar->GetProperty()->SetColor(0.96, 0.96, 0.92);
  scale_bar->GetProperty()->SetAmbient(1.0);  // unlit: reads the same from every side
  scale_bar->GetProperty()->SetDiffuse(0.0);
  scale_bar->GetProperty()->SetSpecular(0.0);
  scale_bar->PickableOff();
  renderer->AddActor(scale_bar);
  scale_label = make<vtkBillboardTextActor3D>();
  scale_label->SetInput(fmt::format("{:g} mm", scale_bar_mm).c_str());
  const Eigen::Vector3d at = start + 0.5 * scale_bar_mm * right + 3.0 * thick * up;
  scale_label->SetPosition(at.x(), at.y(), at.z());
  set_text_style(scale_label->GetTextProperty(), 15, Rgb{0.96, 0.96, 0.92});
  scale_label->GetTextProperty()->SetJustificationToCentered();
  scale_label->GetTextProperty()->SetVerticalJustificationToBottom();
  scale_label->GetTextProperty()->SetBackgroundOpacity(0.0);
  scale_label->GetTextProperty()->SetFrame(false);
  scale_label->PickableOff();
  renderer->AddActor(scale_label);

  // the orientation marker: the model's axes, which are LPS (x to the patient's left, y
  // posterior, z superior), in a small renderer over the 3D view's bottom right corner
  axes = make<vtkAxesActor>();
  axes->SetXAxisLabelText("L");
  axes->SetYAxisLabelText("P");
  axes->SetZAxisLabelText("S");
  axes->SetShaftTypeToCylinder();
  axes->SetCylinderRadius(0.04);
  axes->SetConeRadius(0.45);
  axes->SetTotalLength(1.0, 1.0, 1.0);
  for (vtkCaptionActor2D* c :
       {axes->GetXAxisCaptionActor2D(), axes->GetYAxisCaptionActor2D(), axes->GetZAxisCaptionActor2D()}) {
    c->GetTextActor()->SetTextScaleModeToNone();
    vtkTextProperty* p = c->GetCaptionTextProperty();
    p->SetFontFamilyToArial();
    p->SetFontSize(17);
    p->SetBold(true);
    p->SetItalic(false);
    p->SetShadow(true);
    p->SetColor(0.96, 0.96, 0.92);
  }
  marker = make<vtkRenderer>();
  marker->SetViewport(1.0 - kPanel - 0.14, 0.0, 1.0 - kPanel, 0.24);
  marker->SetLayer(1);
  marker->InteractiveOff();
  marker->AddActor(axes);
  marker->ResetCamera();
  marker_distance = 0.62 * marker->GetActiveCamera()->GetDistance();  // closer than VTK's fit: the axes fill the corner
  window->SetNumberOfLayers(2);
  window->AddRenderer(marker);
}

void ProbeView::Impl::update_marker() {
  if (!marker) return;
  vtkCamera* cam = renderer->GetActiveCamera();
  double dop[3], vu[3];
  cam->GetDirectionOfProjection(dop);
  cam->GetViewUp(vu);
  vtkCamera* m = marker->GetActiveCamera();
  m->SetFocalPoint(0.4, 0.4, 0.4);  // about the middle of the three unit axes
  m->SetPosition(0.4 - marker_distance * dop[0], 0.4 - marker_distance * dop[1], 0.4 - marker_distance * dop[2]);
  m->SetViewUp(vu);
  marker->ResetCameraClippingRange();
}

}  // namespace vx::probe
