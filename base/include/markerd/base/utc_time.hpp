#pragma once
// Wall-clock times as markerd writes and reads them: always UTC, always one of
// these forms, so that every record, run id and report agrees and sorts.

#include <fmt/format.h>

#include <chrono>
#include <iterator>
#include <string>

namespace markerd {

enum class UtcForm {
  compact,       // "20261201T061500Z": run ids and file names
  seconds,       // "2026-12-01T06:15:00Z": status replies
  milliseconds,  // "2026-12-01T06:15:00.123Z": sweep records
  microseconds,  // "2026-12-01T06:15:00.123456Z": the detection log
  readable,      // "2026-12-01 06:15:00 UTC": reports for people
};

// Writes the time in the given form through `out` (an output iterator); with
// a buffer whose capacity suffices, it allocates nothing.
template <class OutputIt>
OutputIt format_utc_to(OutputIt out, std::chrono::system_clock::time_point t, UtcForm form) {
  using namespace std::chrono;
  const auto micros = floor<microseconds>(t);
  const auto day = floor<days>(micros);
  const year_month_day date{day};
  const hh_mm_ss time{micros - day};
  const int y = static_cast<int>(date.year());
  const unsigned mo = static_cast<unsigned>(date.month());
  const unsigned d = static_cast<unsigned>(date.day());
  const auto h = time.hours().count();
  const auto mi = time.minutes().count();
  const auto s = time.seconds().count();
  const auto us = time.subseconds().count();
  switch (form) {
    case UtcForm::compact: return fmt::format_to(out, "{:04}{:02}{:02}T{:02}{:02}{:02}Z", y, mo, d, h, mi, s);
    case UtcForm::seconds: return fmt::format_to(out, "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}Z", y, mo, d, h, mi, s);
    case UtcForm::milliseconds:
      return fmt::format_to(out, "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{:03}Z", y, mo, d, h, mi, s, us / 1000);
    case UtcForm::microseconds:
      return fmt::format_to(out, "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{:06}Z", y, mo, d, h, mi, s, us);
    case UtcForm::readable: return fmt::format_to(out, "{:04}-{:02}-{:02} {:02}:{:02}:{:02} UTC", y, mo, d, h, mi, s);
  }
  return out;
}

[[nodiscard]] inline std::string format_utc(std::chrono::system_clock::time_point t, UtcForm form) {
  std::string text;
  format_utc_to(std::back_inserter(text), t, form);
  return text;
}

// The first year and the last whose every time system_clock holds: it counts
// nanoseconds in 64 bits, from 1677-09-21 to 2262-04-11.
inline constexpr int kFirstUtcYear = 1678;
inline constexpr int kLastUtcYear = 2261;

// Reads UtcForm::milliseconds back. Throws std::runtime_error naming the text
// and what is wrong with it (not of that form, not a date, not a time of day,
// a year outside kFirstUtcYear to kLastUtcYear).
[[nodiscard]] std::chrono::system_clock::time_point parse_utc_milliseconds(const std::string& text);

// Seconds since 1970-01-01T00:00:00Z as a number, to the microsecond: the
// times of Bluesky's event model (sweep/documents.hpp). A double holds a
// microsecond exactly enough to read it back through these years.
[[nodiscard]] double unix_seconds(std::chrono::system_clock::time_point t);
// And back, to the nearest microsecond. Throws std::runtime_error naming the
// number when it is not finite or falls outside kFirstUtcYear to kLastUtcYear.
[[nodiscard]] std::chrono::system_clock::time_point from_unix_seconds(double seconds);

}  // namespace markerd
