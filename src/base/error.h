#pragma once
/// @file error.h
/// The exception type for bad input at the edges (files, options, scenes), and the one for work
/// stopped because its caller asked (Cancelled). Programmer errors are asserts; numeric trouble
/// during a step is a flag in the state.

#include <stdexcept>
#include <string>

namespace vx {

/// Bad input: the message says what is wrong, where, and how to fix it.
class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& message) : std::runtime_error(message) {}
};

/// Work that stopped because its caller asked it to (a cancel flag turned true): not a failure,
/// and nothing it would have kept was kept. The message says what stopped, and where.
class Cancelled : public std::runtime_error {
 public:
  explicit Cancelled(const std::string& message) : std::runtime_error(message) {}
};

}  // namespace vx
