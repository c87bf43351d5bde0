#include "util/log.h"

#include <spdlog/sinks/stdout_sinks.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <memory>

namespace vx::log {
namespace {

std::atomic<Level> g_level{Level::info};

/// One stderr logger, message text only (the prefix says the level where it matters).
spdlog::logger& logger() {
  static const std::shared_ptr<spdlog::logger> l = [] {
    auto sink = std::make_shared<spdlog::sinks::stderr_sink_mt>();
    auto lg = std::make_shared<spdlog::logger>("voxelastic", sink);
    lg->set_pattern("%v");
    lg->set_level(spdlog::level::trace);  // filtered here, by g_level
    lg->flush_on(spdlog::level::trace);
    return lg;
  }();
  return *l;
}

}  // namespace

void set_level(Level level) { g_level = level; }
Level level() { return g_level; }
bool enabled(Level l) { return l >= g_level.load() && g_level.load() != Level::off; }

void info(std::string_view text) {
  if (enabled(Level::info)) logger().info("{}", text);
}
void warn(std::string_view text) {
  if (enabled(Level::warn)) logger().warn("warning: {}", text);
}
void debug(std::string_view text) {
  if (enabled(Level::debug)) logger().debug("debug: {}", text);
}

}  // namespace vx::log
