// The strain the .pvd model frames carry (scene/sim_output.h): the Green-Lagrange strain of each
// element's best-fit deformation gradient and its von Mises equivalent, against the analytic
// values of affine motions, through the frame file ParaView reads.
#include "scene/sim_output.h"

#include <gtest/gtest.h>
#include <unistd.h>
#include <vtkCellData.h>
#include <vtkDataArray.h>
#include <vtkNew.h>
#include <vtkUnstructuredGrid.h>
#include <vtkXMLUnstructuredGridReader.h>

#include <Eigen/Geometry>
#include <cmath>
#include <filesystem>
#include <string>

#include "model/gradational_builder.h"
#include "model/voxel_grid.h"

namespace fs = std::filesystem;
using namespace vx;

namespace {

/// A gradational model of a 12 x 10 x 8 block of 1.5 mm voxels (elements of several levels),
/// or a one-slice 12 x 10 disk-free block (the 2D model).
Model block_model(bool slice) {
  GridGeometry g;
  g.dims = slice ? Eigen::Vector3i(14, 12, 1) : Eigen::Vector3i(14, 12, 10);
  g.spacing_mm = {1.5, 1.5, 1.5};
  g.origin_mm = {-4, 7, 2};
  VoxelGrid grid(g);
  for (int k = slice ? 0 : 1; k < (slice ? 1 : g.dims.z() - 1); ++k)
    for (int j = 1; j < g.dims.y() - 1; ++j)
      for (int i = 1; i < g.dims.x() - 1; ++i) grid.set(i, j, k, 1);
  BuildSettings b;
  b.dimensions = slice ? 2 : 3;
  return build_model(grid, b);
}

/// Every node moved by x -> c + A (X - c).
Eigen::Matrix3Xd affine(const Model& m, const Eigen::Matrix3d& A) {
  const Eigen::Vector3d c(1, 2, 3);
  Eigen::Matrix3Xd x = m.rest_positions;
  for (int i = 0; i < x.cols(); ++i) x.col(i) = c + A * (m.rest_positions.col(i) - c);
  return x;
}

TEST(SimOutputStrain, UniformStretchGivesTheAnalyticStrainInEveryElement) {
  const Model m = block_model(false);
  ASSERT_GT(m.num_elements(), 10);
  const double s = 1.1;  // 10 % along x, nothing across
  const Eigen::Matrix<double, 6, Eigen::Dynamic> E =
      element_green_strain(m, affine(m, Eigen::Vector3d(s, 1, 1).asDiagonal()));
  const double exx = (s * s - 1) / 2;  // 0.105
  for (int e = 0; e < m.num_elements(); ++e) {
    ASSERT_NEAR(E(0, e), exx, 1e-12) << e;
    for (int c = 1; c < 6; ++c) ASSERT_NEAR(E(c, e), 0.0, 1e-12) << e << " " << c;
    // uniaxial strain without lateral strain: the von Mises equivalent is 2/3 of it
    ASSERT_NEAR(von_mises_equivalent_strain(E.col(e)), 2.0 / 3.0 * exx, 1e-12);
  }
  // a simple shear by g: E_xy = g / 2, E_yy = g^2 / 2
  Eigen::Matrix3d shear = Eigen::Matrix3d::Identity();
  shear(0, 1) = 0.2;
  const auto Es = element_green_strain(m, affine(m, shear));
  EXPECT_NEAR(Es(3, 0), 0.1, 1e-12);
  EXPECT_NEAR(Es(1, 0), 0.02, 1e-12);
  EXPECT_NEAR(Es(0, 0), 0.0, 1e-12);
  // a rotation strains nothing
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  EXPECT_LT(element_green_strain(m, affine(m, R)).cwiseAbs().maxCoeff(), 1e-12);
  // an incompressible uniaxial stretch: the equivalent strain is the axial Green strain
  const double l = 1.2;
  const auto Ei =
      element_green_strain(m, affine(m, Eigen::Vector3d(1 / std::sqrt(l), 1 / std::sqrt(l), l).asDiagonal()));
  const Eigen::Matrix<double, 6, 1> ei = Ei.col(0);
  EXPECT_NEAR(ei[2], (l * l - 1) / 2, 1e-12);
  EXPECT_NEAR(ei[0], (1 / l - 1) / 2, 1e-12);
}

TEST(SimOutputStrain, ASliceModelsStrainIsItsInPlaneStrain) {
  const Model m = block_model(true);
  ASSERT_TRUE(m.is_2d());
  const auto E = element_green_strain(m, affine(m, Eigen::Vector3d(1, 0.9, 1).asDiagonal()));
  for (int e = 0; e < m.num_elements(); ++e) {
    ASSERT_NEAR(E(1, e), (0.81 - 1) / 2, 1e-12) << e;
    ASSERT_NEAR(E(0, e), 0.0, 1e-12) << e;
    ASSERT_NEAR(E(2, e), 0.0, 1e-12) << e;
  }
}

TEST(SimOutputStrain, TheModelFrameCarriesTheStrainForParaView) {
  const Model m = block_model(false);
  const fs::path path = fs::temp_directory_path() / ("vx_strain_frame_" + std::to_string(::getpid()) + ".vtu");
  const double s = 1.1;
  const Eigen::Matrix3Xd x = affine(m, Eigen::Vector3d(s, 1, 1).asDiagonal());
  ModelFrameWriter(m).write(x, Eigen::Matrix3Xd::Zero(3, m.num_nodes()), path);
  vtkNew<vtkXMLUnstructuredGridReader> reader;
  reader->SetFileName(path.c_str());
  reader->Update();
  fs::remove(path);
  vtkUnstructuredGrid* ug = reader->GetOutput();
  ASSERT_EQ(ug->GetNumberOfCells(), m.num_elements());
  vtkDataArray* strain = ug->GetCellData()->GetArray("green_strain");
  vtkDataArray* vm = ug->GetCellData()->GetArray("green_strain_von_mises");
  ASSERT_NE(strain, nullptr);
  ASSERT_NE(vm, nullptr);
  ASSERT_EQ(strain->GetNumberOfComponents(), 6);
  EXPECT_STREQ(strain->GetComponentName(0), "XX");
  for (vtkIdType e = 0; e < ug->GetNumberOfCells(); ++e) {
    ASSERT_NEAR(strain->GetComponent(e, 0), 0.105, 1e-12);
    ASSERT_NEAR(strain->GetComponent(e, 3), 0.0, 1e-12);
    ASSERT_NEAR(vm->GetTuple1(e), 0.07, 1e-12);
  }
}

}  // namespace
