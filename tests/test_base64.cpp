// Base64 as RFC 4648 gives it (its test vectors), every byte value through
// and back, and what is not base64 refused.

#include <gtest/gtest.h>

#include <cstdint>
#include <string>
#include <vector>

#include "markerd/base/base64.hpp"

namespace markerd {
namespace {

std::string encode(std::string_view text) {
  return base64_encode({reinterpret_cast<const std::uint8_t*>(text.data()), text.size()});
}

TEST(Base64, TheRfcVectors) {
  EXPECT_EQ(encode(""), "");
  EXPECT_EQ(encode("f"), "Zg==");
  EXPECT_EQ(encode("fo"), "Zm8=");
  EXPECT_EQ(encode("foo"), "Zm9v");
  EXPECT_EQ(encode("foob"), "Zm9vYg==");
  EXPECT_EQ(encode("fooba"), "Zm9vYmE=");
  EXPECT_EQ(encode("foobar"), "Zm9vYmFy");
  const auto decoded = base64_decode("Zm9vYmE=");
  ASSERT_TRUE(decoded.has_value());
  EXPECT_EQ(std::string(decoded->begin(), decoded->end()), "fooba");
}

TEST(Base64, EveryByteValueAndLengthRoundTrips) {
  std::vector<std::uint8_t> bytes;
  for (int n = 0; n < 300; ++n) {
    const auto decoded = base64_decode(base64_encode(bytes));
    ASSERT_TRUE(decoded.has_value()) << n;
    EXPECT_EQ(*decoded, bytes) << n;
    bytes.push_back(static_cast<std::uint8_t>(n * 7 + 3));
  }
}

TEST(Base64, WhatIsNotBase64IsRefused) {
  EXPECT_FALSE(base64_decode("Zm9").has_value()) << "length";
  EXPECT_FALSE(base64_decode("Zm9v!A==").has_value()) << "alphabet";
  EXPECT_FALSE(base64_decode("Zg==Zm9v").has_value()) << "padding before the end";
  EXPECT_FALSE(base64_decode("Z===").has_value()) << "three pads";
  EXPECT_FALSE(base64_decode("Zh==").has_value()) << "bits beyond the byte";
  EXPECT_FALSE(base64_decode("Zm9=").has_value()) << "bits beyond the bytes";
}

}  // namespace
}  // namespace markerd
