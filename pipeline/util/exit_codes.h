#pragma once
/// @file exit_codes.h
/// The exit codes of both programs, `voxelastic` and `voxelastic-probe` (README's table).

#include "base/error.h"

namespace vx {

/// Thrown when the user stopped a run (Ctrl-C) after its outputs were written: exit code
/// `interrupted`, the message says what was kept.
class Interrupted : public Error {
 public:
  using Error::Error;
};

/// Thrown when a picture or window needs an X display and there is none: exit code
/// `no_display` (4), as voxelastic-probe without --headless.
class NoDisplay : public Error {
 public:
  using Error::Error;
};

}  // namespace vx

namespace vx::exit_code {

inline constexpr int ok = 0;            ///< done
inline constexpr int error = 1;         ///< bad input or a failure; the message says what, where and how to fix it
inline constexpr int usage = 2;         ///< the command line itself is wrong (unknown option, missing argument)
inline constexpr int internal = 3;      ///< an internal error (a bug: please report it with the message)
inline constexpr int no_display = 4;    ///< a window is needed and there is no X display (use xvfb-run or --headless)
inline constexpr int interrupted = 130; ///< stopped by Ctrl-C (SIGINT) or SIGTERM; what was done is written

}  // namespace vx::exit_code
