#include "sim/integrator_kind.h"

#include "base/error.h"

namespace vx {

const char* to_string(IntegratorKind k) {
  switch (k) {
    case IntegratorKind::explicit_euler: return "explicit_euler";
    case IntegratorKind::symplectic_euler: return "symplectic_euler";
    case IntegratorKind::implicit: return "implicit";
  }
  return "?";
}

IntegratorKind parse_integrator(const std::string& s) {
  if (s == "explicit_euler") return IntegratorKind::explicit_euler;
  if (s == "symplectic_euler") return IntegratorKind::symplectic_euler;
  if (s == "implicit") return IntegratorKind::implicit;
  throw Error("unknown integrator '" + s + "': use explicit_euler, symplectic_euler or implicit");
}

}  // namespace vx
