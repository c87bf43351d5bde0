#pragma once
/// @file element_faces.h
/// The closed boundary of one element as polygons of its own vertices: the face stream of a
/// VTK_POLYHEDRON cell (model_io) and the faces drawn in pictures (render).

#include <cstdint>
#include <vector>

#include "model/model.h"

namespace vx {

/// Polygons in CSR form: polygon f is nodes[offsets[f] .. offsets[f+1]).
struct FacePolygons {
  std::vector<std::int32_t> offsets{0};  ///< polygons + 1
  std::vector<std::int32_t> nodes;       ///< model node ids, counter-clockwise seen from outside

  [[nodiscard]] int size() const { return int(offsets.size()) - 1; }
  void clear() {
    offsets.assign(1, 0);
    nodes.clear();
  }
};

/// Appends the boundary polygons of element `e` to `out`.
///
/// The element's region is the union of its covered cells. On each axis-aligned plane of its
/// 2x2x2 group, the cell faces between a covered and an uncovered cell that face the same way
/// are merged into edge-connected patches (a square, a 2-cell domino, an L or the full 2x2
/// square); each patch is one planar polygon: its outline corners (corners of the element's
/// region, always vertices) plus every element vertex lying on the outline, in order,
/// oriented so the normal points out of the element. Element vertices inside a patch (hanging
/// nodes of finer neighbours) are not on any polygon; they stay in the element's point list.
///
/// Throws vx::Error when an outline corner is not a vertex of the element (an inconsistent model).
void append_element_faces(const Model& model, int e, FacePolygons& out);

}  // namespace vx
