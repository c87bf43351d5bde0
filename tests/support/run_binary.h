#pragma once
// Running a built binary from a test: exit code and captured output.

#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace vx::testing {

// Under ThreadSanitizer (scripts/tsan.sh builds the apps and their tests with it) a binary runs 5
// to 15 times slower: figures that depend on keeping real time get a wider margin there.
#if defined(__SANITIZE_THREAD__)
inline constexpr bool kUnderTsan = true;
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
inline constexpr bool kUnderTsan = true;
#else
inline constexpr bool kUnderTsan = false;
#endif
#else
inline constexpr bool kUnderTsan = false;
#endif

struct RunResult {
  int code{-1};  ///< exit code; -1 when killed by a signal (a crash)
  std::string out, err;
};

/// The whole file as a string ("" when missing).
inline std::string slurp(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// Runs `binary ARGS` (ARGS shell-quoted by the caller) in `workdir`, with `env` put in front
/// (e.g. "env -u DISPLAY"), stopped after 300 s so a hang fails instead of blocking the suite.
/// stdout and stderr are captured in `capture_dir`/stdout.txt and stderr.txt.
inline RunResult run_binary(const std::filesystem::path& binary, const std::string& args,
                            const std::filesystem::path& workdir, const std::filesystem::path& capture_dir,
                            const std::string& env = "") {
  const std::filesystem::path out = capture_dir / "stdout.txt", err = capture_dir / "stderr.txt";
  const std::string cmd = "cd '" + workdir.string() + "' && " + env + " timeout 300 '" + binary.string() + "' " + args +
                          " >'" + out.string() + "' 2>'" + err.string() + "'";
  const int status = std::system(cmd.c_str());
  RunResult r;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = slurp(out);
  r.err = slurp(err);
  return r;
}

}  // namespace vx::testing
