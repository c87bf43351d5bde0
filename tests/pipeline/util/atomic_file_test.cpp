// Outputs written all-or-nothing (util/atomic_file.h): the text arrives whole, a failed writer
// leaves the old file and no temporary one, the temporary name keeps the target's extensions,
// and a missing folder is named before anything is written.
#include "util/atomic_file.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>

#include "base/error.h"

using namespace vx;
namespace fs = std::filesystem;

namespace {

/// A fresh folder for one test.
fs::path fresh_dir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("vx_atomic_file_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

/// The files in `dir`, names only.
int files_in(const fs::path& dir) {
  int n = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir)) ++n;
  return n;
}

}  // namespace

TEST(AtomicFile, TextArrivesWholeAndReplacesTheOldFile) {
  const fs::path dir = fresh_dir("text");
  const fs::path target = dir / "forces.csv";
  write_text_atomically(target, "a,b\n1,2\n");
  EXPECT_EQ(read_text(target), "a,b\n1,2\n");
  const std::string big(1 << 20, 'x');
  write_text_atomically(target, big);
  EXPECT_EQ(read_text(target), big);
  EXPECT_EQ(files_in(dir), 1);  // no temporary file left beside it
  fs::remove_all(dir);
}

TEST(AtomicFile, AFailedWriterLeavesTheOldFileAndNoTemporary) {
  const fs::path dir = fresh_dir("fail");
  const fs::path target = dir / "summary.json";
  write_text_atomically(target, "old");
  // the writer throws after writing half: the old file stays, the half-written one goes
  try {
    write_atomically(target, [](const fs::path& tmp) {
      std::ofstream(tmp) << "half";
      throw std::runtime_error("disk on fire");
    });
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("could not write"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("disk on fire"), std::string::npos) << e.what();
  }
  EXPECT_EQ(read_text(target), "old");
  EXPECT_EQ(files_in(dir), 1);
  // a writer that writes nothing: an error, the old file stays
  EXPECT_THROW(write_atomically(target, [](const fs::path&) {}), Error);
  EXPECT_EQ(read_text(target), "old");
  // a new target a failed writer never creates
  EXPECT_THROW(write_atomically(dir / "new.txt", [](const fs::path&) { throw std::runtime_error("no"); }), Error);
  EXPECT_FALSE(fs::exists(dir / "new.txt"));
  EXPECT_EQ(files_in(dir), 1);
  fs::remove_all(dir);
}

TEST(AtomicFile, TheTemporaryKeepsTheExtensionsAndTheFolder) {
  const fs::path dir = fresh_dir("ext");
  fs::path seen;
  write_atomically(
      dir / "volume.nii.gz",
      [&](const fs::path& tmp) {
        seen = tmp;
        std::ofstream(tmp) << "x";
      },
      Durability::process_crash);
  EXPECT_EQ(seen.parent_path(), dir);
  const std::string name = seen.filename().string();
  EXPECT_EQ(name.substr(name.size() - 7), ".nii.gz") << name;
  EXPECT_EQ(name.front(), '.') << name;  // hidden while it is written
  EXPECT_NE(seen.filename(), fs::path("volume.nii.gz"));
  EXPECT_EQ(read_text(dir / "volume.nii.gz"), "x");
  EXPECT_FALSE(fs::exists(seen));
  fs::remove_all(dir);
}

TEST(AtomicFile, AMissingFolderOrAFolderAsTargetIsNamed) {
  const fs::path dir = fresh_dir("missing");
  try {
    write_text_atomically(dir / "no" / "such" / "file.txt", "x");
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("does not exist"), std::string::npos) << e.what();
  }
  EXPECT_THROW(check_output_path(dir), Error);  // a folder, not a file name
  EXPECT_NO_THROW(check_output_path(dir / "fine.txt"));
  fs::remove_all(dir);
}
