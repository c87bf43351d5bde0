#include "io/model_io.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <vtkCell.h>
#include <vtkCellData.h>
#include <vtkDataSetSurfaceFilter.h>
#include <vtkFeatureEdges.h>
#include <vtkFieldData.h>
#include <vtkIdList.h>
#include <vtkMassProperties.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPolyData.h>
#include <vtkPolyhedron.h>
#include <vtkStringArray.h>
#include <vtkTriangleFilter.h>
#include <vtkUnstructuredGrid.h>
#include <vtkXMLUnstructuredGridReader.h>
#include <vtkXMLUnstructuredGridWriter.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <utility>

#include "base/error.h"
#include "model/gradational_builder.h"
#include "model/voxel_shapes.h"
#include "support/builder_checks.h"
#include "support/model_test_models.h"

using namespace vx;
using vx::testing::HandElement;
using vx::testing::make_hand_model;
using vx::testing::oblique_grid;
namespace fs = std::filesystem;

namespace {

/// A fresh folder per test, removed afterwards.
class ModelIo : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("vx_model_io_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  /// Files in the folder (to check that failures leave nothing behind).
  [[nodiscard]] std::vector<std::string> files() const {
    std::vector<std::string> names;
    for (const auto& f : fs::directory_iterator(dir_)) names.push_back(f.path().filename().string());
    std::sort(names.begin(), names.end());
    return names;
  }
  fs::path dir_;
};

vtkSmartPointer<vtkUnstructuredGrid> read_vtu(const fs::path& p) {
  vtkNew<vtkXMLUnstructuredGridReader> r;
  r->SetFileName(p.c_str());
  r->Update();
  vtkSmartPointer<vtkUnstructuredGrid> ug = r->GetOutput();
  return ug;
}

/// Volume of a VTK polyhedron cell from its faces (divergence theorem, fan triangles),
/// computed from what VTK returns, independent of voxelastic's face code.
double polyhedron_volume(vtkUnstructuredGrid* ug, vtkIdType cell) {
  auto* poly = vtkPolyhedron::SafeDownCast(ug->GetCell(cell));
  if (!poly) return -1;
  // relative to one point of the cell: coordinates near 1000 mm would cancel badly
  double ref[3];
  poly->GetPoints()->GetPoint(0, ref);
  const Eigen::Vector3d o(ref);
  double v = 0;
  for (int f = 0; f < poly->GetNumberOfFaces(); ++f) {
    vtkCell* face = poly->GetFace(f);
    const vtkIdType n = face->GetNumberOfPoints();
    double p0[3], p1[3], p2[3];
    face->GetPoints()->GetPoint(0, p0);
    for (vtkIdType i = 1; i + 1 < n; ++i) {
      face->GetPoints()->GetPoint(i, p1);
      face->GetPoints()->GetPoint(i + 1, p2);
      const Eigen::Vector3d a = Eigen::Vector3d(p0) - o, b = Eigen::Vector3d(p1) - o, c = Eigen::Vector3d(p2) - o;
      v += a.dot(b.cross(c)) / 6.0;
    }
  }
  return v;
}

/// Directed face edges of a cell that have no reverse edge in another face of the same cell
/// (0 for a closed, consistently oriented surface).
int unmatched_edges(vtkUnstructuredGrid* ug, vtkIdType cell) {
  auto* poly = vtkPolyhedron::SafeDownCast(ug->GetCell(cell));
  std::map<std::pair<vtkIdType, vtkIdType>, int> count;
  for (int f = 0; f < poly->GetNumberOfFaces(); ++f) {
    vtkIdList* ids = poly->GetFace(f)->GetPointIds();
    for (vtkIdType i = 0; i < ids->GetNumberOfIds(); ++i) {
      const vtkIdType a = ids->GetId(i), b = ids->GetId((i + 1) % ids->GetNumberOfIds());
      ++count[{a, b}];
      --count[{b, a}];
    }
  }
  int bad = 0;
  for (const auto& [edge, c] : count) bad += std::abs(c);
  return bad / 2;
}

/// The four hand-made shapes below, on an oblique anisotropic grid.
Model hand_models_mixed() {
  // a level-1 cube (w = 2) with four level-0 elements on its +x face: hanging nodes on that face;
  // an L-shaped partial element; a diagonal-only element (two cells touching at a corner)
  return make_hand_model(
      {
          {{0, 0, 0}, 2, 0xFF, 1},
          {{4, 0, 0}, 1, 0xFF, 0},
          {{4, 2, 0}, 1, 0xFF, 0},
          {{4, 0, 2}, 1, 0xFF, 0},
          {{4, 2, 2}, 1, 0xFF, 0},
          {{0, 6, 0}, 1, 0b0000'0111, 0},
          {{4, 6, 4}, 1, 0b1000'0001, 0},
      },
      oblique_grid({8, 10, 8}));
}

}  // namespace

TEST_F(ModelIo, SingleCubeElementRoundTripAndVolume) {
  const GridGeometry g = oblique_grid({3, 3, 3});
  const Model m = make_hand_model({{{1, 1, 1}, 1, 1, 0}}, g, Layout::voxel);
  ASSERT_EQ(m.validate(), "");
  ASSERT_EQ(m.num_nodes(), 8);
  const fs::path p = dir_ / "cube.vtu";
  save_model(m, p);
  EXPECT_EQ(files(), std::vector<std::string>{"cube.vtu"});  // no temporary file left
  const Model back = load_model(p);
  EXPECT_TRUE(same_model(m, back));
  EXPECT_EQ(back.layout, Layout::voxel);
  EXPECT_EQ(back.grid, m.grid);  // geometry exact (binary doubles)
  EXPECT_NEAR(back.element_volume_mm3[0], 0.5 * 0.8 * 1.25, 1e-12);

  // as VTK sees it: one polyhedron, 6 quads, volume of one voxel
  auto ug = read_vtu(p);
  // the coordinate system as 3D Slicer reads it (field data SPACE = LPS)
  auto* space = vtkStringArray::SafeDownCast(ug->GetFieldData()->GetAbstractArray("SPACE"));
  ASSERT_NE(space, nullptr);
  EXPECT_EQ(space->GetValue(0), "LPS");
  ASSERT_EQ(ug->GetNumberOfCells(), 1);
  EXPECT_EQ(ug->GetCellType(0), VTK_POLYHEDRON);
  auto* poly = vtkPolyhedron::SafeDownCast(ug->GetCell(0));
  ASSERT_NE(poly, nullptr);
  EXPECT_EQ(poly->GetNumberOfFaces(), 6);
  for (int f = 0; f < 6; ++f) EXPECT_EQ(poly->GetFace(f)->GetNumberOfPoints(), 4);
  EXPECT_NEAR(polyhedron_volume(ug, 0), 0.5, 1e-12);
  EXPECT_TRUE(poly->IsConvex());
  EXPECT_EQ(unmatched_edges(ug, 0), 0);
  // and VTK's own surface + mass properties agree
  vtkNew<vtkDataSetSurfaceFilter> surface;
  surface->SetInputData(ug);
  vtkNew<vtkTriangleFilter> tri;
  tri->SetInputConnection(surface->GetOutputPort());
  vtkNew<vtkMassProperties> mass;
  mass->SetInputConnection(tri->GetOutputPort());
  mass->Update();
  EXPECT_NEAR(mass->GetVolume(), 0.5, 1e-9);
  EXPECT_NEAR(mass->GetSurfaceArea(), 2 * (0.5 * 0.8 + 0.8 * 1.25 + 0.5 * 1.25), 1e-9);
  // arrays a viewer shows
  EXPECT_EQ(ug->GetCellData()->GetArray("level")->GetComponent(0, 0), 0);
  EXPECT_EQ(ug->GetCellData()->GetArray("vertex_count")->GetComponent(0, 0), 8);
  EXPECT_NEAR(ug->GetCellData()->GetArray("volume_mm3")->GetComponent(0, 0), 0.5, 1e-12);
  EXPECT_EQ(ug->GetCellData()->GetArray("anchor")->GetNumberOfComponents(), 3);
  EXPECT_EQ(ug->GetPointData()->GetArray("lattice")->GetNumberOfComponents(), 3);
  EXPECT_EQ(ug->GetPointData()->GetArray("surface")->GetComponent(0, 0), 1);
}

TEST_F(ModelIo, TwoElementsSharingAFace) {
  GridGeometry g;
  g.dims = {2, 1, 1};
  const Model m = make_hand_model({{{0, 0, 0}, 1, 1, 0}, {{1, 0, 0}, 1, 1, 0}}, g, Layout::voxel);
  ASSERT_EQ(m.num_nodes(), 12);
  const fs::path p = dir_ / "two.vtu";
  save_model(m, p);
  const Model back = load_model(p);
  EXPECT_TRUE(same_model(m, back));
  auto ug = read_vtu(p);
  ASSERT_EQ(ug->GetNumberOfCells(), 2);
  EXPECT_EQ(ug->GetNumberOfPoints(), 12);
  for (vtkIdType c = 0; c < 2; ++c) {
    EXPECT_NEAR(polyhedron_volume(ug, c), 1.0, 1e-12);
    EXPECT_EQ(unmatched_edges(ug, c), 0);
  }
  // the shared face: 4 points common to both cells
  vtkNew<vtkIdList> a, b;
  ug->GetCellPoints(0, a);
  ug->GetCellPoints(1, b);
  a->IntersectWith(b);
  EXPECT_EQ(a->GetNumberOfIds(), 4);
  // the surface of the pair: a 2 x 1 x 1 box, 10 unit squares, area 10
  vtkNew<vtkDataSetSurfaceFilter> surface;
  surface->SetInputData(ug);
  surface->Update();
  EXPECT_EQ(surface->GetOutput()->GetNumberOfCells(), 10);
}

TEST_F(ModelIo, HangingNodesPartialAndDiagonalElements) {
  const Model m = hand_models_mixed();
  ASSERT_EQ(m.validate(), "");
  // the level-1 cube: 27 corners of its cells plus 16 more on its +x face (5 x 5 points there)
  ASSERT_EQ(m.num_vertices(0), 27 + 16);
  const fs::path p = dir_ / "mixed.vtu";
  save_model(m, p);
  const Model back = load_model(p);
  EXPECT_TRUE(same_model(m, back));
  ASSERT_EQ(back.element_vertices, m.element_vertices);  // the vertex order survives

  auto ug = read_vtu(p);
  ASSERT_EQ(ug->GetNumberOfCells(), m.num_elements());
  const double voxel = 0.5 * 0.8 * 1.25;
  for (int e = 0; e < m.num_elements(); ++e) {
    SCOPED_TRACE("element " + std::to_string(e));
    EXPECT_NEAR(polyhedron_volume(ug, e), m.element_volume_mm3[std::size_t(e)], 1e-9);
    EXPECT_EQ(unmatched_edges(ug, e), 0);
  }
  EXPECT_NEAR(m.element_volume_mm3[0], 64 * voxel, 1e-12);
  EXPECT_NEAR(m.element_volume_mm3[5], 3 * voxel, 1e-12);
  EXPECT_NEAR(m.element_volume_mm3[6], 2 * voxel, 1e-12);
  auto* cube = vtkPolyhedron::SafeDownCast(ug->GetCell(0));
  ASSERT_NE(cube, nullptr);
  // 6 merged faces; the +x face carries its 16 outline points, the 4 faces next to it 10 (corners,
  // edge midpoints and 2 more on the edge they share with it), the -x face 8
  ASSERT_EQ(cube->GetNumberOfFaces(), 6);
  std::vector<vtkIdType> sizes;
  for (int f = 0; f < 6; ++f) sizes.push_back(cube->GetFace(f)->GetNumberOfPoints());
  std::sort(sizes.begin(), sizes.end());
  EXPECT_EQ(sizes, (std::vector<vtkIdType>{8, 10, 10, 10, 10, 16}));
  // L shape: 8 faces (two L-hexagons, and 6 rectangles); diagonal pair: 2 x 6 squares
  EXPECT_EQ(vtkPolyhedron::SafeDownCast(ug->GetCell(5))->GetNumberOfFaces(), 8);
  EXPECT_EQ(vtkPolyhedron::SafeDownCast(ug->GetCell(6))->GetNumberOfFaces(), 12);
}

TEST_F(ModelIo, BuiltModelsRoundTripForEveryResolution) {
  // a ball and a shape with a hole and diagonal contacts, through the real builder
  const VoxelGrid ball = vx::ball_grid(20, 8.3);
  const VoxelGrid odd = vx::testing::make_grid({13, 11, 9}, [](int i, int j, int k) {
    return ((i + j + k) % 3 != 0 && i > 1 && j > 0) || (i < 6 && j < 6 && k < 6);
  });
  for (const VoxelGrid* grid : {&ball, &odd})
    for (Layout r : {Layout::gradational, Layout::uniform, Layout::voxel}) {
      SCOPED_TRACE(std::string(to_string(r)) + (grid == &ball ? " ball" : " odd"));
      BuildSettings s;
      s.layout = r;
      const Model m = build_model(*grid, s);
      const fs::path p = dir_ / (std::string(to_string(r)) + ".vtu");
      save_model(m, p);
      const Model back = load_model(p);
      EXPECT_TRUE(same_model(m, back));
      EXPECT_EQ(back.elements_per_level(), m.elements_per_level());
      EXPECT_EQ(back.covered_voxels(), grid->count());
      // every element's polyhedron is closed and encloses exactly its cells
      auto ug = read_vtu(p);
      ASSERT_EQ(ug->GetNumberOfCells(), m.num_elements());
      double total = 0;
      int bad_volume = 0, open = 0;
      for (int e = 0; e < m.num_elements(); ++e) {
        const double v = polyhedron_volume(ug, e);
        total += v;
        bad_volume += std::fabs(v - m.element_volume_mm3[std::size_t(e)]) > 1e-9;
        open += unmatched_edges(ug, e) != 0;
      }
      EXPECT_EQ(bad_volume, 0);
      EXPECT_EQ(open, 0);
      EXPECT_NEAR(total, double(grid->count()), 1e-6);
    }
}

TEST_F(ModelIo, SliceModelsRoundTripAsPolygonsOnTheirPlane) {
  // a 2D (slice) model in an oblique slice: VTK_POLYGON cells whose areas (times the slice
  // thickness) are the element volumes, all in the slice plane facing its normal; the model
  // comes back identical, dimensions 2
  GridGeometry g;
  g.dims = {30, 24, 1};
  g.spacing_mm = {0.5, 0.7, 3.0};
  g.origin_mm = {-10, 20, 5};
  g.direction = Eigen::AngleAxisd(0.6, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  const VoxelGrid slice = vx::testing::make_grid({30, 24, 1}, [](int i, int j, int) {
    return (i - 15) * (i - 15) + (j - 12) * (j - 12) < 110 && !(i > 18 && j < 8);
  });
  VoxelGrid grid(g);
  grid.data() = slice.data();
  const Eigen::Vector3d normal = g.direction.col(0).cross(g.direction.col(1));
  for (Layout r : {Layout::gradational, Layout::voxel}) {
    SCOPED_TRACE(to_string(r));
    BuildSettings s;
    s.layout = r;
    s.dimensions = 2;
    const Model m = build_model(grid, s);
    const fs::path p = dir_ / (std::string("slice_") + to_string(r) + ".vtu");
    save_model(m, p);
    const Model back = load_model(p);
    EXPECT_EQ(back.dimensions, 2);
    EXPECT_TRUE(same_model(m, back));
    auto ug = read_vtu(p);
    ASSERT_EQ(ug->GetNumberOfCells(), m.num_elements());
    int wrong = 0;
    for (int e = 0; e < m.num_elements(); ++e) {
      if (ug->GetCellType(e) != VTK_POLYGON) ++wrong;
      vtkCell* cell = ug->GetCell(e);
      Eigen::Vector3d twice = Eigen::Vector3d::Zero();  // the polygon's area vector (shoelace)
      const int n = int(cell->GetNumberOfPoints());
      for (int k = 0; k < n; ++k) {
        Eigen::Vector3d a, b;
        ug->GetPoint(cell->GetPointId(k), a.data());
        ug->GetPoint(cell->GetPointId((k + 1) % n), b.data());
        twice += a.cross(b);
      }
      const double area = 0.5 * twice.dot(normal);
      if (std::fabs(area * 3.0 - m.element_volume_mm3[std::size_t(e)]) > 1e-9) ++wrong;
    }
    EXPECT_EQ(wrong, 0);
  }
}

TEST_F(ModelIo, SaveRejectsBadPathsAndLeavesNothing) {
  const Model m = hand_models_mixed();
  try {
    save_model(m, dir_ / "model.vtk");
    FAIL() << "a .vtk name was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(".vtu"), std::string::npos) << e.what();
  }
  try {
    save_model(m, dir_ / "no_such_folder" / "model.vtu");
    FAIL() << "a missing folder was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("does not exist"), std::string::npos) << e.what();
  }
  Model broken = m;
  broken.element_vertices[3] = 9999;
  EXPECT_THROW(save_model(broken, dir_ / "broken.vtu"), Error);
  EXPECT_TRUE(files().empty());
}

TEST_F(ModelIo, LoadRejectsOtherFilesClearly) {
  const auto message = [](const fs::path& p) {
    try {
      (void)load_model(p);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  // missing file, folder, text file
  EXPECT_NE(message(dir_ / "nope.vtu").find("no such file"), std::string::npos);
  EXPECT_NE(message(dir_).find("folder"), std::string::npos);
  std::ofstream(dir_ / "text.vtu") << "hello, not a model\n";
  EXPECT_NE(message(dir_ / "text.vtu").find("not a VTK XML unstructured grid"), std::string::npos)
      << message(dir_ / "text.vtu");

  // a valid .vtu that is not a voxelastic model
  const Model m = hand_models_mixed();
  const fs::path good = dir_ / "good.vtu";
  save_model(m, good);
  {
    auto ug = read_vtu(good);
    vtkNew<vtkUnstructuredGrid> plain;
    plain->CopyStructure(ug);
    vtkNew<vtkXMLUnstructuredGridWriter> w;
    w->SetInputData(plain);
    w->SetFileName((dir_ / "plain.vtu").c_str());
    ASSERT_EQ(w->Write(), 1);
  }
  EXPECT_NE(message(dir_ / "plain.vtu").find("not a voxelastic model"), std::string::npos)
      << message(dir_ / "plain.vtu");

  // a voxelastic model missing one array: the message names it
  {
    auto ug = read_vtu(good);
    ug->GetCellData()->RemoveArray("anchor");
    vtkNew<vtkXMLUnstructuredGridWriter> w;
    w->SetInputData(ug);
    w->SetFileName((dir_ / "no_anchor.vtu").c_str());
    ASSERT_EQ(w->Write(), 1);
  }
  const std::string no_anchor = message(dir_ / "no_anchor.vtu");
  EXPECT_NE(no_anchor.find("'anchor'"), std::string::npos) << no_anchor;
  EXPECT_NE(no_anchor.find("missing"), std::string::npos) << no_anchor;

  // truncated files, cut at several places: an error, never a crash or a wrong model
  const auto size = fs::file_size(good);
  std::string bytes(size, '\0');
  std::ifstream(good, std::ios::binary).read(bytes.data(), std::streamsize(size));
  for (double frac : {0.1, 0.3, 0.5, 0.7, 0.9, 0.99}) {
    const fs::path cut = dir_ / "cut.vtu";
    std::ofstream(cut, std::ios::binary | std::ios::trunc).write(bytes.data(), std::streamsize(double(size) * frac));
    SCOPED_TRACE("cut at " + std::to_string(frac));
    const std::string msg = message(cut);
    EXPECT_NE(msg, "no error");
    EXPECT_NE(msg.find("cut.vtu"), std::string::npos) << msg;  // says where
    if (std::getenv("VX_VERBOSE")) std::printf("%s\n", msg.c_str());
  }
  // flipped bytes in the compressed data
  std::string damaged = bytes;
  for (std::size_t i = damaged.size() * 3 / 4; i < damaged.size() * 3 / 4 + 64 && i < damaged.size(); ++i) damaged[i] ^= 0x5A;
  std::ofstream(dir_ / "damaged.vtu", std::ios::binary).write(damaged.data(), std::streamsize(damaged.size()));
  try {
    const Model loaded = load_model(dir_ / "damaged.vtu");
    // if VTK read it without complaint, the data must still pass the checks and match
    EXPECT_EQ(loaded.validate(), "");
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("damaged.vtu"), std::string::npos) << e.what();
  }
}
