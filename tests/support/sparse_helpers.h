#pragma once
/// @file sparse_helpers.h
/// Test helpers for the sparse factor (sim/sparse_factor.h): a model's elastic matrix plus a
/// diagonal, and a factor cache in memory.
#include <Eigen/Sparse>

#include <cstdint>
#include <cstring>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "physics/elements.h"
#include "physics/physics_model.h"
#include "sim/sparse_factor.h"

namespace vx::testing {

/// sum_e K_e (element_elastic_matrix) over the model's nodes plus diag(diagonal(node)):
/// symmetric positive definite for a positive diagonal.
template <typename Diagonal>
SparseFactor::Matrix elastic_matrix_plus(const PhysicsModel& p, Diagonal diagonal) {
  const Model& m = *p.model;
  std::vector<Eigen::Triplet<double>> t;
  Eigen::MatrixXd ke;
  for (int e = 0; e < p.num_elements(); ++e) {
    element_elastic_matrix(p, e, ke);
    const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
    for (int i = 0; i < n; ++i)
      for (int j = 0; j < n; ++j) t.emplace_back(m.element_vertices[b + i], m.element_vertices[b + j], ke(i, j));
  }
  const int nn = m.num_nodes();
  for (int i = 0; i < nn; ++i) t.emplace_back(i, i, diagonal(i));
  SparseFactor::Matrix a(nn, nn);
  a.setFromTriplets(t.begin(), t.end());
  return a;
}

/// `bytes` in 8-byte aligned memory (as a mapped file is), kept alive by the pointer.
inline std::shared_ptr<const void> aligned_copy(const std::string& bytes) {
  auto buf = std::shared_ptr<std::uint64_t[]>(new std::uint64_t[bytes.size() / 8 + 1]);
  std::memcpy(buf.get(), bytes.data(), bytes.size());
  return std::shared_ptr<const void>(buf, buf.get());
}

/// What SparseFactor::write writes.
inline std::string bytes_of(const SparseFactor& f) {
  std::ostringstream out;
  f.write(out);
  return out.str();
}

/// A factor cache in memory (the folder one is io/factor_cache.h) that counts its loads.
class MemoryFactorCache final : public FactorCache {
 public:
  bool load(const FactorKey& key, SparseFactor& factor) override {
    ++loads;
    const auto it = files.find(key.name());
    if (it == files.end()) return false;
    const std::shared_ptr<const void> mem = aligned_copy(it->second);
    return factor.read(static_cast<const unsigned char*>(mem.get()), it->second.size(), mem);
  }
  void store(const FactorKey& key, const SparseFactor& factor) override { files[key.name()] = bytes_of(factor); }
  std::map<std::string, std::string> files;
  int loads{0};
};

}  // namespace vx::testing
