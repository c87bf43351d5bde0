#include "util/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <fstream>
#include <system_error>

#include "base/error.h"

namespace vx {
namespace fs = std::filesystem;

void check_output_path(const fs::path& path) {
  const fs::path dir = path.has_parent_path() ? path.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw Error("cannot write '" + path.string() + "': folder '" + dir.string() +
                "' does not exist (create it first)");
  if (::access(dir.c_str(), W_OK) != 0)
    throw Error("cannot write '" + path.string() + "': folder '" + dir.string() +
                "' is not writable (choose another output folder or fix its permissions)");
  if (fs::is_directory(path, ec))
    throw Error("cannot write '" + path.string() + "': it is a folder, give a file name");
}

void sync_file(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw Error("cannot open '" + path.string() + "' to flush it to disk");
  const int rc = ::fsync(fd);
  ::close(fd);
  if (rc != 0) throw Error("cannot flush '" + path.string() + "' to disk (fsync failed: disk full or failing?)");
}

void sync_folder(const fs::path& folder) {
  const int fd = ::open(folder.empty() ? "." : folder.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  (void)::fsync(fd);
  ::close(fd);
}

void write_atomically(const fs::path& path, const std::function<void(const fs::path&)>& write, Durability durability) {
  check_output_path(path);
  static std::atomic<unsigned> counter{0};
  // keep the full extension chain (".nii.gz") so writers that look at it still work
  const std::string name = path.filename().string();
  const auto dot = name.find('.');
  const std::string stem = dot == std::string::npos ? name : name.substr(0, dot);
  const std::string ext = dot == std::string::npos ? "" : name.substr(dot);
  const fs::path tmp = path.parent_path() /
                       ("." + stem + ".tmp" + std::to_string(::getpid()) + "_" + std::to_string(counter++) + ext);
  std::error_code ec;
  try {
    write(tmp);
    if (!fs::exists(tmp, ec)) throw Error("the writer produced no file");
    if (durability == Durability::power_loss) sync_file(tmp);  // the data first, then the name
    fs::rename(tmp, path, ec);
    if (ec) throw Error("rename failed: " + ec.message());
    if (durability == Durability::power_loss) sync_folder(path.parent_path());
  } catch (const std::exception& e) {
    fs::remove(tmp, ec);
    throw Error("could not write '" + path.string() + "': " + e.what());
  }
}

void write_text_atomically(const fs::path& path, const std::string& text) {
  write_atomically(path, [&](const fs::path& tmp) {
    std::ofstream out(tmp, std::ios::binary);
    out << text;
    out.close();
    if (!out) throw Error("write error (disk full?)");
  });
}

}  // namespace vx
