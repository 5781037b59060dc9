#include "markerd/base/uuid.hpp"

#include <gtest/gtest.h>

#include <regex>
#include <set>
#include <string>

namespace markerd {
namespace {

TEST(Uuid, IsARandomVersion4Uuid) {
  // Lowercase hex, 8-4-4-4-12; version 4; variant 10xx (8, 9, a or b).
  const std::regex form("[0-9a-f]{8}-[0-9a-f]{4}-4[0-9a-f]{3}-[89ab][0-9a-f]{3}-[0-9a-f]{12}");
  std::set<std::string> seen;
  for (int i = 0; i < 100; ++i) {
    const std::string uid = new_uuid4();
    EXPECT_TRUE(std::regex_match(uid, form)) << uid;
    seen.insert(uid);
  }
  EXPECT_EQ(seen.size(), 100U);
}

}  // namespace
}  // namespace markerd
