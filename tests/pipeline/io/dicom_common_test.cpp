// The DICOM file test shared by the volume reader's dispatch and the DICOM series reader: one
// has_dicm_magic, and an unreadable file is an error that says so (not "not a DICOM file").
#include "io/dicom_common.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <string>

#include "base/error.h"
#include "io/dicom_series.h"
#include "io/volume_io.h"

namespace fs = std::filesystem;

namespace {

class DicmMagic : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::path(VX_BINARY_DIR) / "test_scratch" / "dicom_common_test" /
           ::testing::UnitTest::GetInstance()->current_test_info()->name();
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    std::error_code ec;
    fs::permissions(dir_ / "IM0002", fs::perms::owner_all, ec);
    if (!HasFailure()) fs::remove_all(dir_);
  }
  void write(const fs::path& p, const std::string& bytes) const {
    std::ofstream(p, std::ios::binary) << bytes;
  }
  /// Makes `p` unreadable; false when the process reads it anyway (root).
  static bool make_unreadable(const fs::path& p) {
    fs::permissions(p, fs::perms::none);
    return !std::ifstream(p, std::ios::binary);
  }
  fs::path dir_;
};

/// The message an unreadable file gives, naming it and the likely cause.
void expect_unreadable_error(const std::function<void()>& f, const fs::path& file) {
  try {
    f();
    ADD_FAILURE() << "no error for the unreadable " << file;
  } catch (const vx::Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("cannot open '" + file.string() + "' for reading"), std::string::npos) << what;
    EXPECT_NE(what.find("permissions"), std::string::npos) << what;
  }
}

TEST_F(DicmMagic, PreambleThenDicmMarks_ShortOrOtherFilesDoNot) {
  write(dir_ / "a", std::string(128, '\0') + "DICM" + std::string(20, 'x'));
  write(dir_ / "b", std::string(128, '\0') + "DICX" + std::string(20, 'x'));
  write(dir_ / "c", std::string(128, '\0') + "DIC");
  write(dir_ / "d", "");
  EXPECT_TRUE(vx::dicom::has_dicm_magic(dir_ / "a"));
  EXPECT_FALSE(vx::dicom::has_dicm_magic(dir_ / "b"));
  EXPECT_FALSE(vx::dicom::has_dicm_magic(dir_ / "c"));
  EXPECT_FALSE(vx::dicom::has_dicm_magic(dir_ / "d"));
}

TEST_F(DicmMagic, AFileThatCannotBeOpenedIsAnErrorNotANonDicomFile) {
  // a file that went away since it was listed fails to open like an unreadable one
  expect_unreadable_error([&] { (void)vx::dicom::has_dicm_magic(dir_ / "gone"); }, dir_ / "gone");
}

TEST_F(DicmMagic, UnreadableFilesAreReportedByBothReaders) {
  // a file without extension goes through the magic test in read_volume; in a folder, the
  // series reader tests every file: both say the file cannot be read, and why
  write(dir_ / "IM0002", std::string(128, '\0') + "DICM");
  if (!make_unreadable(dir_ / "IM0002")) GTEST_SKIP() << "this process reads files without read permission (root)";
  expect_unreadable_error([&] { (void)vx::read_volume(dir_ / "IM0002"); }, dir_ / "IM0002");
  expect_unreadable_error([&] { (void)vx::read_dicom_series({dir_}); }, dir_ / "IM0002");
}

}  // namespace
