#include "io/element_faces.h"

#include <algorithm>
#include <array>
#include <string>
#include <utility>

#include "base/error.h"

namespace vx {

void append_element_faces(const Model& model, int e, FacePolygons& out) {
  const int w = model.element_cell_voxels[std::size_t(e)];
  const std::uint8_t cells = model.element_cells[std::size_t(e)];
  const Eigen::Vector3i anchor = model.element_anchor.col(e);
  const std::int64_t side = 2 * std::int64_t(w) + 1;

  // the element's vertices by local lattice position (key = x + side*(y + side*z))
  std::vector<std::pair<std::int64_t, std::int32_t>> vertex_at;
  const int b = model.element_offsets[std::size_t(e)], n = model.element_offsets[std::size_t(e) + 1] - b;
  vertex_at.reserve(std::size_t(n));
  for (int i = 0; i < n; ++i) {
    const std::int32_t node = model.element_vertices[std::size_t(b + i)];
    const Eigen::Vector3i q = model.node_lattice.col(node) - anchor;
    if ((q.array() < 0).any() || (q.array() > 2 * w).any()) continue;  // off the group: on no face
    vertex_at.emplace_back(q.x() + side * (q.y() + side * std::int64_t(q.z())), node);
  }
  std::sort(vertex_at.begin(), vertex_at.end());
  const auto find_vertex = [&](const std::array<int, 3>& q) -> std::int32_t {
    const std::int64_t key = q[0] + side * (q[1] + side * std::int64_t(q[2]));
    const auto it = std::lower_bound(vertex_at.begin(), vertex_at.end(), std::make_pair(key, std::int32_t(-1)));
    return it != vertex_at.end() && it->first == key ? it->second : -1;
  };
  const auto covered = [cells](int cx, int cy, int cz) {
    return cx >= 0 && cx < 2 && cy >= 0 && cy < 2 && cz >= 0 && cz < 2 && (cells >> (cx + 2 * cy + 4 * cz) & 1);
  };

  // for each axis, each of the 3 planes across it and each facing, the boundary cell faces
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;  // e_u x e_v = e_axis
    for (int p = 0; p < 3; ++p) {
      for (int facing = +1; facing >= -1; facing -= 2) {
        // patch[a][c]: cell face (a along u, c along v) lies on the boundary with this facing
        bool patch[2][2];
        int count = 0;
        for (int a = 0; a < 2; ++a)
          for (int c = 0; c < 2; ++c) {
            std::array<int, 3> below{}, above{};
            below[axis] = p - 1, above[axis] = p;
            below[u] = above[u] = a;
            below[v] = above[v] = c;
            const bool lo = covered(below[0], below[1], below[2]), hi = covered(above[0], above[1], above[2]);
            patch[a][c] = facing > 0 ? (lo && !hi) : (hi && !lo);
            count += patch[a][c];
          }
        if (count == 0) continue;
        // split into edge-connected components (only a diagonal pair is disconnected in 2x2)
        int component[2][2] = {{-1, -1}, {-1, -1}};
        int components = 0;
        for (int a = 0; a < 2; ++a)
          for (int c = 0; c < 2; ++c) {
            if (!patch[a][c] || component[a][c] >= 0) continue;
            component[a][c] = components;
            // neighbours of (a,c) in 2x2: (1-a,c) and (a,1-c); a third square joins through either
            for (int pass = 0; pass < 2; ++pass)
              for (int x = 0; x < 2; ++x)
                for (int y = 0; y < 2; ++y)
                  if (component[x][y] == components) {
                    if (patch[1 - x][y] && component[1 - x][y] < 0) component[1 - x][y] = components;
                    if (patch[x][1 - y] && component[x][1 - y] < 0) component[x][1 - y] = components;
                  }
            ++components;
          }
        for (int k = 0; k < components; ++k) {
          // directed outline edges, counter-clockwise in (u,v): next[start] = end, points 0..2 each way
          int next[9];
          std::fill(std::begin(next), std::end(next), -1);
          const auto in_k = [&](int a, int c) { return a >= 0 && a < 2 && c >= 0 && c < 2 && component[a][c] == k; };
          int start = -1;
          for (int a = 0; a < 2; ++a)
            for (int c = 0; c < 2; ++c) {
              if (!in_k(a, c)) continue;
              // the square's 4 edges counter-clockwise, each with the square across it
              const int corners[4][2] = {{a, c}, {a + 1, c}, {a + 1, c + 1}, {a, c + 1}};
              const int across[4][2] = {{a, c - 1}, {a + 1, c}, {a, c + 1}, {a - 1, c}};
              for (int s = 0; s < 4; ++s) {
                if (in_k(across[s][0], across[s][1])) continue;
                const int from = corners[s][0] + 3 * corners[s][1];
                const int to = corners[(s + 1) % 4][0] + 3 * corners[(s + 1) % 4][1];
                next[from] = to;
                if (start < 0) start = from;
              }
            }
          // walk the outline; along each unit edge step through the lattice points (w per edge)
          std::vector<std::int32_t> polygon;
          int at = start, guard = 0;
          do {
            const int to = next[at];
            const int au = at % 3, av = at / 3, tu = to % 3, tv = to / 3;
            const int prev = [&] {
              for (int q = 0; q < 9; ++q)
                if (next[q] == at) return q;
              return -1;
            }();
            const bool turning = prev < 0 || (at % 3 - prev % 3 != tu - au) || (at / 3 - prev / 3 != tv - av);
            for (int t = 0; t < w; ++t) {
              std::array<int, 3> q{};
              q[axis] = p * w;
              q[u] = au * w + (tu - au) * t;
              q[v] = av * w + (tv - av) * t;
              const std::int32_t node = find_vertex(q);
              if (node >= 0) {
                polygon.push_back(node);
              } else if (t == 0 && turning) {
                throw Error("the model is inconsistent: element " + std::to_string(e) +
                            " has no vertex at its corner (lattice " + std::to_string(anchor.x() + q[0]) + "," +
                            std::to_string(anchor.y() + q[1]) + "," + std::to_string(anchor.z() + q[2]) +
                            "); rebuild the model with `voxelastic convert`");
              }
            }
            at = to;
          } while (at != start && ++guard < 9);
          if (facing < 0) std::reverse(polygon.begin(), polygon.end());
          out.nodes.insert(out.nodes.end(), polygon.begin(), polygon.end());
          out.offsets.push_back(std::int32_t(out.nodes.size()));
        }
      }
    }
  }
}

}  // namespace vx
