#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "markerd/base/read_file.hpp"
#include "support/temp_dir.hpp"

using markerd::check_regular_file;
using markerd::FileError;
using markerd::read_regular_file;

namespace {

std::string error_of(const std::filesystem::path& path, std::size_t max_bytes) {
  try {
    (void)read_regular_file(path, max_bytes, "the plan");
  } catch (const FileError& e) {
    return e.what();
  }
  return "(no error)";
}

}  // namespace

TEST(ReadRegularFile, ReadsAWholeFile) {
  const markerd::test_support::TempDir dir;
  std::string text(100000, 'x');
  text += "end";
  EXPECT_EQ(read_regular_file(dir.write("whole", text), 200000, "the plan"), text);
}

TEST(ReadRegularFile, RefusesWhatIsNotARegularFileByKind) {
  EXPECT_EQ(error_of("/tmp", 1000), "/tmp: the plan is a directory, not a file");
  EXPECT_EQ(error_of("/dev/zero", 1000), "/dev/zero: the plan is a character device, not a file");
  const markerd::test_support::TempDir dir;
  const auto fifo = dir / "fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  // Would block forever in open() or read() if the kind were not checked first.
  EXPECT_EQ(error_of(fifo, 1000), fifo.string() + ": the plan is a FIFO, not a file");
}

TEST(ReadRegularFile, RefusesAFileOverTheLimitWithItsSize) {
  const markerd::test_support::TempDir dir;
  const auto path = dir.write("large", std::string(70 * 1024, 'x'));
  EXPECT_EQ(error_of(path, 64 * 1024),
            path.string() + ": the plan is 70 KiB (71680 bytes), larger than the 64 KiB allowed");
}

TEST(ReadRegularFile, NamesAMissingFileAndItsCause) {
  EXPECT_EQ(error_of("/nonexistent/plan.toml", 1000),
            "/nonexistent/plan.toml: the plan cannot be read: No such file or directory");
}

// Callers word a missing file their own way ("no such rig file"); every
// other reason stays FileError's message.
TEST(CheckRegularFile, TellsAMissingFileFromOneThatCannotBeUsed) {
  const auto missing = [](const std::filesystem::path& path) {
    try {
      (void)check_regular_file(path, 1000, "the rig file");
    } catch (const FileError& e) {
      return e.missing();
    }
    ADD_FAILURE() << "no error for " << path;
    return false;
  };
  EXPECT_TRUE(missing("/nonexistent/rig.toml"));
  EXPECT_TRUE(missing("/dev/null/rig.toml"));  // ENOTDIR: no such file either
  EXPECT_FALSE(missing("/tmp"));
  EXPECT_FALSE(missing("/tmp/" + std::string(300, 'x')));
}

// ENAMETOOLONG says which limit the name breaks.
TEST(ReadRegularFile, NamesANameTooLongAndTheLimit) {
  const std::string long_name = "/tmp/" + std::string(256, 'p') + "/plan.toml";
  EXPECT_EQ(error_of(long_name, 1000),
            long_name +
                ": the plan cannot be used: a name in its path is 256 bytes long, longer than the 255 a file "
                "system takes");
  std::string long_path = "/tmp";
  while (long_path.size() < 5000) long_path += "/" + std::string(200, 'd');
  EXPECT_EQ(error_of(long_path, 1000), long_path + ": the plan cannot be used: its path is " +
                                           std::to_string(long_path.size()) +
                                           " bytes long, longer than the 4095 a path may be");
}
