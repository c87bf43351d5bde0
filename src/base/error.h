#pragma once
/// @file error.h
/// The one exception type for bad input at the edges (files, options, scenes).
/// Programmer errors are asserts; numeric trouble during a step is a flag in the state.

#include <stdexcept>
#include <string>

namespace vx {

/// Bad input: the message says what is wrong, where, and how to fix it.
class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& message) : std::runtime_error(message) {}
};

}  // namespace vx
