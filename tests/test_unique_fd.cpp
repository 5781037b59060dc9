#include "markerd/base/unique_fd.hpp"

#include <fcntl.h>
#include <gtest/gtest.h>

#include <cerrno>

#include "markerd/base/errno_text.hpp"

namespace markerd {
namespace {

TEST(ErrnoText, TheSystemsWords) {
  EXPECT_EQ(errno_text(ENOENT), "No such file or directory");
  EXPECT_EQ(errno_text(EACCES), "Permission denied");
  EXPECT_NE(errno_text(123456).find("123456"), std::string::npos);
}

TEST(UniqueFd, ClosesWhatItOwnsOnce) {
  int raw = ::open("/dev/null", O_RDONLY | O_CLOEXEC);
  ASSERT_GE(raw, 0);
  {
    UniqueFd fd(raw);
    EXPECT_TRUE(fd.valid());
    UniqueFd moved = std::move(fd);
    EXPECT_FALSE(fd.valid());  // NOLINT(bugprone-use-after-move): the state after a move is the contract
    EXPECT_EQ(moved.get(), raw);
  }
  EXPECT_EQ(::fcntl(raw, F_GETFD), -1);  // closed when its owner went
  EXPECT_EQ(errno, EBADF);

  raw = ::open("/dev/null", O_RDONLY | O_CLOEXEC);
  ASSERT_GE(raw, 0);
  UniqueFd kept(raw);
  const int released = kept.release();
  EXPECT_FALSE(kept.valid());
  EXPECT_NE(::fcntl(released, F_GETFD), -1);  // released, not closed
  UniqueFd again(released);
  EXPECT_EQ(again.close(), 0);
  EXPECT_EQ(again.close(), 0);  // nothing left to close
  EXPECT_EQ(::fcntl(released, F_GETFD), -1);
}

}  // namespace
}  // namespace markerd
