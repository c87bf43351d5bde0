#include "physics/physics_model.h"

#include <string>

#include "base/error.h"

namespace vx {

const char* to_string(ElementKind kind) {
  switch (kind) {
    case ElementKind::paper: return "paper";
    case ElementKind::hourglass: return "hourglass";
  }
  return "?";
}

ElementKind element_kind_from_string(const std::string& name) {
  for (const ElementKind k : {ElementKind::paper, ElementKind::hourglass})
    if (name == to_string(k)) return k;
  throw Error("unknown element '" + name + "': choose paper or hourglass");
}

double PhysicsModel::total_mass_kg() const {
  double m = 0;
  for (double x : node_mass_kg) m += x;
  return m;
}

}  // namespace vx
