#include "scene/sim_output.h"

#include <fmt/format.h>
#include <vtkCellArray.h>
#include <vtkCellData.h>
#include <vtkDoubleArray.h>
#include <vtkIdTypeArray.h>
#include <vtkIntArray.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkSmartPointer.h>
#include <vtkUnstructuredGrid.h>
#include <vtkXMLPolyDataWriter.h>
#include <vtkXMLUnstructuredGridWriter.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>
#include <sstream>

#include "base/error.h"
#include "io/element_faces.h"
#include "io/vtk_arrays.h"
#include "physics/material.h"
#include "render/plot.h"
#include "util/atomic_file.h"
#include "util/vtk_messages.h"

namespace vx {
namespace fs = std::filesystem;

// ---------------------------------------------------------------------------------------------
// forces

ForceRecorder::ForceRecorder(const Simulation& sim, const DeviceSide* device, double interval_s)
    : device_side_(device), device_(device && device->has_device()), interval_s_(std::max(interval_s, 0.0)) {
  const int np = sim.num_probes();
  for (int i = 0; i < np; ++i) names_.push_back(sim.settings().probes[std::size_t(i)].name);
  sum_.assign(std::size_t(np), Eigen::Vector3d::Zero());
  contacts_.assign(std::size_t(np), 0);
  const double dt = sim.dt_s();
  const double steps_per_row = std::max(1.0, std::round(interval_s_ / dt));
  interval_s_ = steps_per_row * dt;
  rows_.reserve(std::size_t(np) * 1024);
  emit(sim);  // t = 0
  next_s_ = sim.time_s() + interval_s_;
}

void ForceRecorder::emit(const Simulation& sim) {
  for (int i = 0; i < sim.num_probes(); ++i) {
    const ProbeOutput& o = sim.probe(i);
    ForceRow r;
    r.time_s = sim.time_s();
    r.probe = i;
    r.position_mm = o.pose.position_mm;
    r.raw_n = steps_ > 0 ? Eigen::Vector3d(sum_[std::size_t(i)] / steps_) : Eigen::Vector3d::Zero();
    if (device_side_) r.shaped_n = device_side_->output(i).shaped_force_n;
    r.contacts = contacts_[std::size_t(i)];
    rows_.push_back(r);
    sum_[std::size_t(i)].setZero();
    contacts_[std::size_t(i)] = 0;
  }
  steps_ = 0;
}

void ForceRecorder::record(const Simulation& sim) {
  for (int i = 0; i < sim.num_probes(); ++i) {
    const ProbeOutput& o = sim.probe(i);
    sum_[std::size_t(i)] += o.raw_force_n;
    contacts_[std::size_t(i)] = std::max(contacts_[std::size_t(i)], o.contacts);
    max_step_force_ = std::max(max_step_force_, o.raw_force_n.norm());
  }
  max_wall_force_ = std::max(max_wall_force_, sim.wall_force_n().norm());
  wall_impulse_ += sim.wall_force_n() * sim.dt_s();
  ++steps_;
  if (sim.time_s() >= next_s_ - 0.5 * sim.dt_s()) {
    emit(sim);
    next_s_ += interval_s_;
  }
}

void ForceRecorder::finish(const Simulation& sim) {
  if (steps_ > 0) emit(sim);
}

double ForceRecorder::max_force_n() const {
  double m = 0;
  for (const auto& r : rows_) m = std::max(m, r.raw_n.norm());
  return m;
}

double ForceRecorder::max_force_n(int probe) const {
  double m = 0;
  for (const auto& r : rows_)
    if (r.probe == probe) m = std::max(m, r.raw_n.norm());
  return m;
}

void ForceRecorder::write_csv(const fs::path& path) const {
  std::string out;
  out.reserve(rows_.size() * 160 + 100);
  out += "time_s,probe,x_mm,y_mm,z_mm,fx_n,fy_n,fz_n,dfx_n,dfy_n,dfz_n\n";
  for (const auto& r : rows_) {
    out += fmt::format("{:.9g},{},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},", r.time_s, names_[std::size_t(r.probe)],
                       r.position_mm.x(), r.position_mm.y(), r.position_mm.z(), r.raw_n.x(), r.raw_n.y(), r.raw_n.z());
    if (device_) out += fmt::format("{:.9g},{:.9g},{:.9g}\n", r.shaped_n.x(), r.shaped_n.y(), r.shaped_n.z());
    else out += ",,\n";
  }
  write_text_atomically(path, out);
}

void indentation_curve(const std::vector<ForceRow>& rows, int probe, std::vector<double>& depth,
                       std::vector<double>& force) {
  depth.clear();
  force.clear();
  // the direction the tissue pushes the probe: its mean force while in contact
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  const ForceRow* first = nullptr;
  for (const auto& r : rows)
    if (r.probe == probe && r.contacts > 0) {
      if (!first) first = &r;
      mean += r.raw_n;
    }
  if (!first || !(mean.norm() > 0)) return;
  const Eigen::Vector3d dir = mean.normalized();
  for (const auto& r : rows) {
    if (r.probe != probe) continue;
    depth.push_back(-(r.position_mm - first->position_mm).dot(dir));
    force.push_back(r.raw_n.dot(dir));
  }
}

std::vector<Press> find_presses(const std::vector<ForceRow>& rows) {
  std::vector<Press> out;
  int probes = 0;
  for (const auto& r : rows) probes = std::max(probes, r.probe + 1);
  for (int p = 0; p < probes; ++p) {
    std::optional<Press> cur;
    int gap = 0, in_contact = 0;
    auto close = [&] {
      if (cur && in_contact >= 3) out.push_back(*cur);
      cur.reset();
      in_contact = 0;
    };
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const ForceRow& r = rows[i];
      if (r.probe != p) continue;
      if (r.contacts > 0) {
        if (!cur) cur = Press{p, i, i, r.time_s, r.time_s};
        cur->last = i;
        cur->end_s = r.time_s;
        ++in_contact;
        gap = 0;
      } else if (cur && ++gap > kPressGapRows) {
        close();
      }
    }
    close();
  }
  std::sort(out.begin(), out.end(), [](const Press& a, const Press& b) { return a.start_s < b.start_s; });
  return out;
}

double hertz_bonded_layer_n(double e_kpa, double nu, double r, double d, double h) {
  constexpr double kPi = std::numbers::pi;
  const double a0 = -(1.2876 - 1.4678 * nu + 1.3442 * nu * nu) / (1 - nu);
  const double b0 = (0.6387 - 1.0277 * nu + 1.5164 * nu * nu) / (1 - nu);
  const double x = std::sqrt(r * d) / h;
  const double c = 1 - 2 * a0 / kPi * x + 4 * a0 * a0 / (kPi * kPi) * x * x -
                   8 / (kPi * kPi * kPi) * (a0 * a0 * a0 + 4 * kPi * kPi * b0 / 15) * x * x * x +
                   16 * a0 / (kPi * kPi * kPi * kPi) * (a0 * a0 * a0 + 3 * kPi * kPi * b0 / 5) * x * x * x * x;
  return 4.0 / 3.0 * e_kpa * kKpaToNPerMm2 / (1 - nu * nu) * std::sqrt(r) * std::pow(d, 1.5) * c;
}

void plot_forces(const ForceRecorder& rec, const fs::path& png, const std::vector<ForceReference>& references) {
  static const char* colours[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#17becf"};
  const std::size_t probes = rec.names().size();
  const bool one = probes == 1;
  PlotPanel time;
  time.title = one ? "Force on the " + rec.names()[0] + " against time" : "Force on the probes against time";
  time.xlabel = "time (s)";
  time.ylabel = one ? "force on the " + rec.names()[0] + " (N)" : "force on the probe (N)";
  for (std::size_t p = 0; p < probes; ++p) {
    const std::string& name = rec.names()[p];
    PlotSeries raw, dev;
    raw.title = one ? "tissue on the " + name : name;
    raw.line_width = 1.6;
    dev.title = one ? "device force (half sines)" : name + ": device force (half sines)";
    dev.line_width = 1.3;
    raw.color = dev.color = colours[p % 7];
    dev.dash_type = 2;
    for (const auto& r : rec.rows())
      if (r.probe == int(p)) {
        raw.x.push_back(r.time_s);
        raw.y.push_back(r.raw_n.norm());
        dev.x.push_back(r.time_s);
        dev.y.push_back(r.shaped_n.norm());
      }
    time.series.push_back(std::move(raw));
    if (rec.has_device()) time.series.push_back(std::move(dev));
  }
  // force against depth, one curve per press: its own first contact and direction
  PlotPanel depth;
  depth.title = "Force against indentation depth, each press from its first contact";
  depth.xlabel = "indentation depth (mm)";
  depth.ylabel = "force along the press (N)";
  const std::vector<Press> presses = find_presses(rec.rows());
  std::vector<int> count(probes, 0);
  for (const Press& q : presses) ++count[std::size_t(q.probe)];
  std::vector<int> seen(probes, 0);
  double dmax = 0;
  for (std::size_t k = 0; k < presses.size(); ++k) {
    const Press& q = presses[k];
    const std::vector<ForceRow> rows(rec.rows().begin() + std::ptrdiff_t(q.first),
                                     rec.rows().begin() + std::ptrdiff_t(q.last) + 1);
    PlotSeries s;
    s.line_width = 1.6;
    indentation_curve(rows, q.probe, s.x, s.y);
    if (s.x.empty()) continue;
    for (double d : s.x) dmax = std::max(dmax, d);
    const std::string& name = rec.names()[std::size_t(q.probe)];
    const int n = ++seen[std::size_t(q.probe)];
    const std::string when = fmt::format("{:.3g} to {:.3g} s", q.start_s, q.end_s);
    s.title = count[std::size_t(q.probe)] > 1 ? fmt::format("{}, press {} ({})", name, n, when)
                                              : fmt::format("{} ({})", name, when);
    s.color = presses.size() == probes ? colours[std::size_t(q.probe) % 7] : colours[k % 7];
    depth.series.push_back(std::move(s));
  }
  for (const ForceReference& ref : references) {
    if (!(dmax > 0)) break;
    PlotSeries s;
    s.title = ref.title;
    s.line_width = 2.0;
    s.color = "black";
    s.dash_type = 2;
    for (int i = 0; i <= 80; ++i) {
      const double d = dmax * i / 80.0;
      s.x.push_back(d);
      s.y.push_back(hertz_bonded_layer_n(ref.e_kpa, ref.nu, ref.radius_mm, d, ref.layer_mm));
    }
    depth.series.push_back(std::move(s));
  }
  plot_png({time, depth}, png, 1000, 440);
}

// ---------------------------------------------------------------------------------------------
// ParaView series

PvdSeries::PvdSeries(const fs::path& dir, const std::string& name, const std::string& ext)
    : dir_(dir), name_(name), ext_(ext) {
  std::error_code ec;
  fs::create_directories(dir_ / name_, ec);
  if (ec) throw Error(fmt::format("cannot create {}: {}", (dir_ / name_).string(), ec.message()));
}

fs::path PvdSeries::next_frame_path() const {
  return dir_ / name_ / fmt::format("{}_{:06d}.{}", name_, times_.size(), ext_);
}

void PvdSeries::add(double t) { times_.push_back(t); }

fs::path PvdSeries::collection_path() const { return dir_ / (name_ + ".pvd"); }

void PvdSeries::finish() const {
  std::ostringstream x;
  x << "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n"
       "  <Collection>\n";
  for (std::size_t i = 0; i < times_.size(); ++i)
    x << fmt::format("    <DataSet timestep=\"{:.9g}\" group=\"\" part=\"0\" file=\"{}/{}_{:06d}.{}\"/>\n", times_[i],
                     name_, name_, i, ext_);
  x << "  </Collection>\n</VTKFile>\n";
  write_text_atomically(collection_path(), x.str());
}

namespace {

vtkSmartPointer<vtkDoubleArray> vectors(const char* name, vtkIdType n) {
  auto a = vtkSmartPointer<vtkDoubleArray>::New();
  a->SetName(name);
  a->SetNumberOfComponents(3);
  a->SetNumberOfTuples(n);
  return a;
}

template <class Writer, class Data>
void write_xml(Data* data, const fs::path& path) {
  // a frame of a series: atomic, not fsynced (hundreds per run; the .pvd is written durably)
  mark_lps(data->GetFieldData());  // 3D Slicer shows the frames in place
  write_atomically(path, [&](const fs::path& tmp) {
    VtkMessageCapture capture;
    vtkNew<Writer> w;
    w->SetFileName(tmp.c_str());
    w->SetInputData(data);
    w->SetDataModeToBinary();
    w->SetCompressorTypeToZLib();
    if (w->Write() != 1 || !capture.errors().empty())
      throw Error(fmt::format("cannot write {}: {}", path.string(), capture.first_error("the VTK writer failed")));
  }, Durability::process_crash);
}

}  // namespace

Eigen::Matrix<double, 6, Eigen::Dynamic> element_green_strain(const Model& m, const Eigen::Matrix3Xd& x) {
  const int ne = m.num_elements();
  Eigen::Matrix<double, 6, Eigen::Dynamic> strain(6, ne);
  // a slice model's vertices span the plane only: F keeps the slice normal
  const Eigen::Vector3d normal = m.grid.direction.col(2).normalized();
#pragma omp parallel for schedule(static)
  for (int e = 0; e < ne; ++e) {
    const int a = m.element_offsets[std::size_t(e)], b = m.element_offsets[std::size_t(e) + 1];
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (int v = a; v < b; ++v) centroid += x.col(m.element_vertices[std::size_t(v)]);
    centroid /= double(b - a);
    // F = (sum dx dX^T) (sum dX dX^T)^-1, dX the rest offsets from the rest centroid
    Eigen::Matrix3d xX = Eigen::Matrix3d::Zero(), XX = Eigen::Matrix3d::Zero();
    for (int v = a; v < b; ++v) {
      const Eigen::Vector3d dX = m.rest_offsets.col(v);
      xX += (x.col(m.element_vertices[std::size_t(v)]) - centroid) * dX.transpose();
      XX += dX * dX.transpose();
    }
    if (m.is_2d()) {
      const double s = XX.trace();
      xX += s * normal * normal.transpose();
      XX += s * normal * normal.transpose();
    }
    const Eigen::Matrix3d F = xX * XX.inverse();
    const Eigen::Matrix3d E = 0.5 * (F.transpose() * F - Eigen::Matrix3d::Identity());
    strain.col(e) << E(0, 0), E(1, 1), E(2, 2), E(0, 1), E(1, 2), E(0, 2);
  }
  return strain;
}

double von_mises_equivalent_strain(const Eigen::Matrix<double, 6, 1>& s) {
  const double mean = (s[0] + s[1] + s[2]) / 3.0;
  const double dxx = s[0] - mean, dyy = s[1] - mean, dzz = s[2] - mean;
  const double contraction = dxx * dxx + dyy * dyy + dzz * dzz + 2.0 * (s[3] * s[3] + s[4] * s[4] + s[5] * s[5]);
  return std::sqrt(2.0 / 3.0 * contraction);
}

struct ModelFrameWriter::Impl {
  const Model* model{nullptr};
  vtkSmartPointer<vtkUnstructuredGrid> grid;
  vtkSmartPointer<vtkPoints> points;
  vtkSmartPointer<vtkDoubleArray> displacement, velocity, strain, strain_von_mises;
};

ModelFrameWriter::ModelFrameWriter(const Model& m) : impl_(std::make_unique<Impl>()) {
  impl_->model = &m;
  const int nn = m.num_nodes(), ne = m.num_elements();
  auto& ug = impl_->grid;
  ug = vtkSmartPointer<vtkUnstructuredGrid>::New();
  impl_->points = vtkSmartPointer<vtkPoints>::New();
  impl_->points->SetDataTypeToDouble();
  impl_->points->SetNumberOfPoints(nn);
  ug->SetPoints(impl_->points);
  insert_element_polyhedra(m, ug);
  vtkNew<vtkIntArray> level;
  level->SetName("level");
  level->SetNumberOfTuples(ne);
  for (int e = 0; e < ne; ++e) level->SetValue(e, m.element_level[std::size_t(e)]);
  ug->GetCellData()->AddArray(level);
  impl_->strain = vtkSmartPointer<vtkDoubleArray>::New();
  impl_->strain->SetName("green_strain");
  impl_->strain->SetNumberOfComponents(6);
  impl_->strain->SetNumberOfTuples(ne);
  const char* components[6] = {"XX", "YY", "ZZ", "XY", "YZ", "XZ"};  // ParaView's symmetric-tensor order
  for (int c = 0; c < 6; ++c) impl_->strain->SetComponentName(c, components[c]);
  impl_->strain_von_mises = vtkSmartPointer<vtkDoubleArray>::New();
  impl_->strain_von_mises->SetName("green_strain_von_mises");
  impl_->strain_von_mises->SetNumberOfTuples(ne);
  ug->GetCellData()->AddArray(impl_->strain);
  ug->GetCellData()->AddArray(impl_->strain_von_mises);
  impl_->displacement = vectors("displacement_mm", nn);
  impl_->velocity = vectors("velocity_mm_s", nn);
  ug->GetPointData()->AddArray(impl_->displacement);
  ug->GetPointData()->AddArray(impl_->velocity);
  ug->GetPointData()->SetActiveVectors("displacement_mm");
}

ModelFrameWriter::~ModelFrameWriter() = default;

void ModelFrameWriter::write(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v, const fs::path& path) const {
  const Model& m = *impl_->model;
  for (int i = 0; i < m.num_nodes(); ++i) {
    impl_->points->SetPoint(i, x.col(i).data());
    const Eigen::Vector3d d = x.col(i) - m.rest_positions.col(i);
    impl_->displacement->SetTuple(i, d.data());
    impl_->velocity->SetTuple(i, v.col(i).data());
  }
  const Eigen::Matrix<double, 6, Eigen::Dynamic> strain = element_green_strain(m, x);
  for (int e = 0; e < m.num_elements(); ++e) {
    const Eigen::Matrix<double, 6, 1> s = strain.col(e);
    impl_->strain->SetTuple(e, s.data());
    impl_->strain_von_mises->SetValue(e, von_mises_equivalent_strain(s));
  }
  impl_->strain->Modified();
  impl_->strain_von_mises->Modified();
  impl_->points->Modified();
  impl_->displacement->Modified();
  impl_->velocity->Modified();
  write_xml<vtkXMLUnstructuredGridWriter>(impl_->grid.Get(), path);
}

struct SurfaceFrameWriter::Impl {
  const EmbeddedSurface* surface{nullptr};
  vtkSmartPointer<vtkPolyData> poly;
  vtkSmartPointer<vtkPoints> points;
  vtkSmartPointer<vtkDoubleArray> normals, displacement;
  Eigen::Matrix3Xd normal_buffer;
};

SurfaceFrameWriter::SurfaceFrameWriter(const EmbeddedSurface& s) : impl_(std::make_unique<Impl>()) {
  impl_->surface = &s;
  const int nv = s.num_vertices(), nt = s.num_triangles();
  impl_->poly = vtkSmartPointer<vtkPolyData>::New();
  impl_->points = vtkSmartPointer<vtkPoints>::New();
  impl_->points->SetDataTypeToDouble();
  impl_->points->SetNumberOfPoints(nv);
  impl_->poly->SetPoints(impl_->points);
  vtkNew<vtkCellArray> tris;
  tris->AllocateExact(nt, 3 * nt);
  for (int t = 0; t < nt; ++t) {
    const vtkIdType ids[3] = {s.triangles(0, t), s.triangles(1, t), s.triangles(2, t)};
    tris->InsertNextCell(3, ids);
  }
  impl_->poly->SetPolys(tris);
  impl_->normals = vectors("Normals", nv);
  impl_->displacement = vectors("displacement_mm", nv);
  impl_->poly->GetPointData()->SetNormals(impl_->normals);
  impl_->poly->GetPointData()->AddArray(impl_->displacement);
}

SurfaceFrameWriter::~SurfaceFrameWriter() = default;

void SurfaceFrameWriter::write(const Eigen::Matrix3Xd& vertices, const fs::path& path) const {
  const EmbeddedSurface& s = *impl_->surface;
  compute_vertex_normals(s, vertices, impl_->normal_buffer);
  for (int i = 0; i < s.num_vertices(); ++i) {
    impl_->points->SetPoint(i, vertices.col(i).data());
    impl_->normals->SetTuple(i, impl_->normal_buffer.col(i).data());
    const Eigen::Vector3d d = vertices.col(i) - s.rest_vertices.col(i);
    impl_->displacement->SetTuple(i, d.data());
  }
  impl_->points->Modified();
  impl_->normals->Modified();
  impl_->displacement->Modified();
  write_xml<vtkXMLPolyDataWriter>(impl_->poly.Get(), path);
}

void write_probe_frame(const Simulation& sim, const DeviceSide* device_side, const fs::path& path) {
  const int np = sim.num_probes();
  vtkNew<vtkPolyData> poly;
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(np);
  vtkNew<vtkCellArray> verts;
  auto force = vectors("force_n", np);
  auto device = vectors("device_force_n", np);
  auto axis = vectors("axis", np);
  vtkNew<vtkDoubleArray> radius;
  radius->SetName("radius_mm");
  radius->SetNumberOfTuples(np);
  for (int i = 0; i < np; ++i) {
    const ProbeOutput& o = sim.probe(i);
    const ProbeGeometry& g = sim.settings().probes[std::size_t(i)].geometry;
    points->SetPoint(i, o.pose.position_mm.data());
    const vtkIdType id = i;
    verts->InsertNextCell(1, &id);
    force->SetTuple(i, o.raw_force_n.data());
    const Eigen::Vector3d shaped = device_side ? device_side->output(i).shaped_force_n : Eigen::Vector3d::Zero();
    device->SetTuple(i, shaped.data());
    axis->SetTuple(i, g.axis.data());
    radius->SetValue(i, g.radius_mm);
  }
  poly->SetPoints(points);
  poly->SetVerts(verts);
  poly->GetPointData()->AddArray(force);
  poly->GetPointData()->AddArray(device);
  poly->GetPointData()->AddArray(axis);
  poly->GetPointData()->AddArray(radius);
  write_xml<vtkXMLPolyDataWriter>(poly.Get(), path);
}

}  // namespace vx
