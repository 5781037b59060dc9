#include "markerd/base/ascii.hpp"

#include <gtest/gtest.h>

namespace markerd {
namespace {

TEST(AsciiLower, LowersAsciiLettersOnly) {
  EXPECT_EQ(ascii_lower(".PNG"), ".png");
  EXPECT_EQ(ascii_lower("Exposure Time, Absolute"), "exposure time, absolute");
  EXPECT_EQ(ascii_lower("MM 2.5"), "mm 2.5");
  EXPECT_EQ(ascii_lower(""), "");
}

TEST(AsciiLower, LeavesOtherBytesAsTheyAre) {
  // UTF-8 "Ä" (C3 84) and bytes above 0x7F: a locale's tolower could change them.
  const std::string text = "\xC3\x84Z\x80\xFF@[`{";
  EXPECT_EQ(ascii_lower(text), "\xC3\x84z\x80\xFF@[`{");
}

}  // namespace
}  // namespace markerd
