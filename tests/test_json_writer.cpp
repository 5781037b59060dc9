#include "markerd/base/json_writer.hpp"

#include <gtest/gtest.h>

#include <array>
#include <limits>

namespace markerd {
namespace {

TEST(JsonWriter, PlacesCommasAndColonsAtEveryDepth) {
  std::string out;
  JsonWriter json(out);
  json.begin_object();
  json.key("a").integer(1);
  json.key("b").begin_array();
  json.begin_object().end_object();
  json.begin_array().integer(2).integer(3).end_array();
  json.begin_array().end_array();
  json.null();
  json.end_array();
  json.key("c").begin_object();
  json.key("d").boolean(true);
  json.key("e").boolean(false);
  json.end_object();
  json.key("f").string("x");
  json.end_object();
  EXPECT_EQ(out, R"({"a":1,"b":[{},[2,3],[],null],"c":{"d":true,"e":false},"f":"x"})");
}

TEST(JsonWriter, AppendsToWhatTheBufferHolds) {
  std::string out = "prefix ";
  JsonWriter json(out);
  json.begin_array().integer(-7).integer(std::uint64_t{18446744073709551615u}).end_array();
  EXPECT_EQ(out, "prefix [-7,18446744073709551615]");
}

TEST(JsonWriter, NumbersWithTheirDecimalsAndNonFiniteAsNull) {
  std::string out;
  JsonWriter json(out);
  const std::array<double, 5> values{1.0 / 3.0, -2.5, std::numeric_limits<double>::quiet_NaN(),
                                     std::numeric_limits<double>::infinity(), 1e300};
  json.numbers(values, 3);
  EXPECT_EQ(out.substr(0, 37), "[0.333,-2.500,null,null,1000000000000");
  EXPECT_EQ(out.back(), ']');
}

TEST(JsonWriter, StringsEscapeControlsAndReplaceWhatIsNotUtf8) {
  std::string out;
  JsonWriter json(out);
  json.begin_array();
  json.string("quote \" backslash \\ newline \n tab \t bell \x07");
  json.string("caf\xC3\xA9 \xE2\x82\xAC \xF0\x9F\x98\x80");    // valid: kept
  json.string("\xC0\xAF \xED\xA0\x80 \xF4\x90\x80\x80 \xC3");  // overlong, surrogate, beyond U+10FFFF, cut short
  json.end_array();
  EXPECT_EQ(out,
            "[\"quote \\\" backslash \\\\ newline \\n tab \\t bell \\u0007\","
            "\"caf\xC3\xA9 \xE2\x82\xAC \xF0\x9F\x98\x80\","
            "\"\xEF\xBF\xBD\xEF\xBF\xBD \xEF\xBF\xBD\xEF\xBF\xBD\xEF\xBF\xBD "
            "\xEF\xBF\xBD\xEF\xBF\xBD\xEF\xBF\xBD\xEF\xBF\xBD "
            "\xEF\xBF\xBD\"]");
}

TEST(JsonWriter, AllocatesNothingOnceTheBufferIsLargeEnough) {
  std::string out;
  out.reserve(256);
  const auto* data = out.data();
  JsonWriter json(out);
  json.begin_object();
  json.key("time").utc(std::chrono::system_clock::time_point{}, UtcForm::microseconds);
  json.key("pi").number(3.14159265, 6);
  json.key("name").string("camera 0");
  json.end_object();
  EXPECT_EQ(out.data(), data);
  EXPECT_EQ(out, R"({"time":"1970-01-01T00:00:00.000000Z","pi":3.141593,"name":"camera 0"})");
}

}  // namespace
}  // namespace markerd
