#include "markerd/base/utc_time.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>

namespace markerd {
namespace {

using namespace std::chrono;

// 2026-12-01T06:15:07.123456Z
const system_clock::time_point kTime =
    sys_days{year{2026} / December / 1} + hours{6} + minutes{15} + seconds{7} + microseconds{123456};

TEST(UtcTime, EveryForm) {
  EXPECT_EQ(format_utc(kTime, UtcForm::compact), "20261201T061507Z");
  EXPECT_EQ(format_utc(kTime, UtcForm::seconds), "2026-12-01T06:15:07Z");
  EXPECT_EQ(format_utc(kTime, UtcForm::milliseconds), "2026-12-01T06:15:07.123Z");
  EXPECT_EQ(format_utc(kTime, UtcForm::microseconds), "2026-12-01T06:15:07.123456Z");
  EXPECT_EQ(format_utc(kTime, UtcForm::readable), "2026-12-01 06:15:07 UTC");
}

TEST(UtcTime, TimesBeforeTheEpochRoundDown) {
  // Half a millisecond before 1970: still 1969's last second, not 1970's first.
  const auto t = system_clock::time_point{} - microseconds{500};
  EXPECT_EQ(format_utc(t, UtcForm::microseconds), "1969-12-31T23:59:59.999500Z");
  EXPECT_EQ(format_utc(t, UtcForm::milliseconds), "1969-12-31T23:59:59.999Z");
}

TEST(UtcTime, MillisecondsReadBack) {
  const auto t = floor<milliseconds>(kTime);
  EXPECT_EQ(parse_utc_milliseconds(format_utc(t, UtcForm::milliseconds)), t);
  EXPECT_EQ(parse_utc_milliseconds("1678-01-01T00:00:00.000Z"), sys_days{year{1678} / January / 1});
}

TEST(UtcTime, WhatIsNotATimeIsNamed) {
  const auto error = [](const std::string& text) {
    try {
      (void)parse_utc_milliseconds(text);
    } catch (const std::runtime_error& e) {
      return std::string(e.what());
    }
    return std::string("(no error)");
  };
  EXPECT_EQ(error("2026-12-01 06:15:07.123Z"),
            "not a UTC time of the form 2026-12-01T06:15:00.123Z: \"2026-12-01 06:15:07.123Z\"");
  EXPECT_EQ(error("2026-12-01T06:15:07.123"),
            "not a UTC time of the form 2026-12-01T06:15:00.123Z: \"2026-12-01T06:15:07.123\"");
  EXPECT_EQ(error("2026-02-30T06:15:07.123Z"), "not a date: \"2026-02-30T06:15:07.123Z\"");
  EXPECT_EQ(error("1677-12-31T23:59:59.999Z"),
            "year 1677 is outside 1678 to 2261, the years markerd's clock holds: \"1677-12-31T23:59:59.999Z\"");
  EXPECT_EQ(error("2262-01-01T00:00:00.000Z").substr(0, 34), "year 2262 is outside 1678 to 2261,");
  for (const std::string clock :
       {"24:00:00.000Z", "06:60:00.000Z", "06:15:60.000Z", "06:-1:00.000Z", "06:15:00.-12Z"}) {
    EXPECT_EQ(error("2026-12-01T" + clock), "not a time of day: \"2026-12-01T" + clock + "\"");
  }
}

TEST(UtcTime, UnixSecondsReadBackToTheMicrosecond) {
  EXPECT_DOUBLE_EQ(unix_seconds(sys_days{year{1970} / January / 1} + seconds{90}), 90.0);
  EXPECT_EQ(from_unix_seconds(unix_seconds(kTime)), kTime);
  const auto before_1970 = system_clock::time_point{} - microseconds{1'500'001};
  EXPECT_EQ(from_unix_seconds(unix_seconds(before_1970)), before_1970);
}

TEST(UtcTime, UnixSecondsOutsideTheClocksYearsAreRefused) {
  for (const double bad : {std::nan(""), HUGE_VAL, -1e10, 1e10}) {
    EXPECT_THROW((void)from_unix_seconds(bad), std::runtime_error) << bad;
  }
  try {
    (void)from_unix_seconds(9.3e9);
    ADD_FAILURE() << "9.3e9 s was read";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("outside 1678 to 2261"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace markerd
