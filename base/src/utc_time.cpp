#include "markerd/base/utc_time.hpp"

#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace markerd {

std::chrono::system_clock::time_point parse_utc_milliseconds(const std::string& text) {
  using namespace std::chrono;
  int y = 0;
  unsigned mo = 0, d = 0, h = 0, mi = 0, s = 0, ms = 0;
  char z = 0;
  if (std::sscanf(text.c_str(), "%d-%u-%uT%u:%u:%u.%3u%c", &y, &mo, &d, &h, &mi, &s, &ms, &z) != 8 || z != 'Z') {
    throw std::runtime_error(fmt::format("not a UTC time of the form 2026-12-01T06:15:00.123Z: \"{}\"", text));
  }
  if (y < kFirstUtcYear || y > kLastUtcYear) {
    throw std::runtime_error(fmt::format("year {} is outside {} to {}, the years markerd's clock holds: \"{}\"", y,
                                         kFirstUtcYear, kLastUtcYear, text));
  }
  const year_month_day date{year{y}, month{mo}, day{d}};
  if (!date.ok()) throw std::runtime_error(fmt::format("not a date: \"{}\"", text));
  // sscanf's %u takes a minus sign and wraps it: unbounded hours or minutes
  // would overflow the clock as a year would.
  if (h > 23 || mi > 59 || s > 59 || ms > 999) throw std::runtime_error(fmt::format("not a time of day: \"{}\"", text));
  return sys_days{date} + hours{h} + minutes{mi} + seconds{s} + milliseconds{ms};
}

double unix_seconds(std::chrono::system_clock::time_point t) {
  using namespace std::chrono;
  return static_cast<double>(floor<microseconds>(t).time_since_epoch().count()) / 1e6;
}

std::chrono::system_clock::time_point from_unix_seconds(double seconds) {
  using namespace std::chrono;
  const double first =
      static_cast<double>(sys_seconds{sys_days{year{kFirstUtcYear} / January / 1}}.time_since_epoch().count());
  const double end =
      static_cast<double>(sys_seconds{sys_days{year{kLastUtcYear + 1} / January / 1}}.time_since_epoch().count());
  if (!std::isfinite(seconds) || seconds < first || seconds >= end) {
    throw std::runtime_error(fmt::format("{} seconds since 1970 is outside {} to {}, the years markerd's clock holds",
                                         seconds, kFirstUtcYear, kLastUtcYear));
  }
  return system_clock::time_point{duration_cast<system_clock::duration>(microseconds{std::llround(seconds * 1e6)})};
}

}  // namespace markerd
