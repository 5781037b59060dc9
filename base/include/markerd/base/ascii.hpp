#pragma once
// Text that markerd compares without regard to case (file extensions, format
// and control names) is ASCII: lowering it must not depend on the C locale.

#include <string>
#include <string_view>

namespace markerd {

[[nodiscard]] inline std::string ascii_lower(std::string_view text) {
  std::string out(text);
  for (char& c : out) {
    if (c >= 'A' && c <= 'Z') c = static_cast<char>(c - 'A' + 'a');
  }
  return out;
}

}  // namespace markerd
