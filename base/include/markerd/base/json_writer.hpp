#pragma once
// Writes one JSON value into a string, placing its own commas and colons, so
// that a record's code says only what goes in. It appends to the caller's
// buffer and allocates nothing once that buffer has grown to a record's size:
// the detection log writes a line per frame with it.
//
//   JsonWriter json(buffer);
//   json.begin_object();
//   json.key("id").integer(7);
//   json.key("corners").begin_array();
//   for (double v : xs) json.number(v, 4);
//   json.end_array();
//   json.end_object();

#include <chrono>
#include <cstdint>
#include <iterator>
#include <span>
#include <string>
#include <string_view>

#include "markerd/base/utc_time.hpp"

namespace markerd {

class JsonWriter {
 public:
  // Nesting deeper than this is a programming error (records are shallow).
  static constexpr int kMaxDepth = 63;

  explicit JsonWriter(std::string& out) : out_(out) {}

  JsonWriter& begin_object() { return open('{'); }
  JsonWriter& end_object() { return close('}'); }
  JsonWriter& begin_array() { return open('['); }
  JsonWriter& end_array() { return close(']'); }

  // A member's name, inside an object; the next value is its value. Names are
  // the program's own, plain ASCII, and written as they are.
  JsonWriter& key(std::string_view name);

  // JSON has no NaN or infinity: a non-finite number is written as null.
  JsonWriter& number(double value, int decimals);
  template <class Integer>
  JsonWriter& integer(Integer value) {
    before_value();
    fmt::format_to(std::back_inserter(out_), "{}", value);
    return *this;
  }
  JsonWriter& boolean(bool value);
  JsonWriter& null();
  // Arbitrary bytes as a JSON string: control characters escaped (no newline
  // can split a line), bytes that are not UTF-8 replaced by U+FFFD (every line
  // parses, whatever a device name holds).
  JsonWriter& string(std::string_view text);
  JsonWriter& utc(std::chrono::system_clock::time_point t, UtcForm form);
  // An array of numbers.
  JsonWriter& numbers(std::span<const double> values, int decimals);

 private:
  JsonWriter& open(char bracket);
  JsonWriter& close(char bracket);
  void before_value();
  void escape_ascii(unsigned char c);

  std::string& out_;
  int depth_ = 0;
  std::uint64_t has_items_ = 0;  // bit d: the container at depth d holds an item already
  bool after_key_ = false;
};

}  // namespace markerd
