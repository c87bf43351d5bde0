#pragma once
/// @file progress.h
/// Console progress for long work: a bar on a terminal; otherwise (a log, a pipe) a line every
/// 10%, and the time taken, only for work that has run over a second.

#include <chrono>
#include <cstdio>
#include <string>

namespace vx {

/// Reports progress of one task to stderr (shown only while the log level shows notes: `-q`
/// hides it). Thread-compatible (call from one thread).
class Progress {
 public:
  /// `label` names the task; `enabled` false makes every call a no-op (quiet mode).
  explicit Progress(std::string label, bool enabled = true);
  ~Progress();
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;

  /// Sets the fraction done, 0..1 (values are clamped; output is rate-limited).
  void update(double fraction);
  /// Marks the task finished and prints its wall time.
  void done();

 private:
  std::string label_;
  bool enabled_;
  bool tty_;
  bool finished_{false};
  int last_decile_{-1};
  int last_permille_{-1};
  std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point last_draw_;
};

}  // namespace vx
