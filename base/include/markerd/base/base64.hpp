#pragma once
// Base64 (RFC 4648, the standard alphabet, with padding): how binary data,
// a snapshot's image, travels in the control socket's JSON lines.

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace markerd {

[[nodiscard]] std::string base64_encode(std::span<const std::uint8_t> bytes);
// Nothing when `text` is not base64: a character outside the alphabet, a
// length that is not a multiple of 4, padding anywhere but at the end, or
// bits set in the padding that no byte holds.
[[nodiscard]] std::optional<std::vector<std::uint8_t>> base64_decode(std::string_view text);

}  // namespace markerd
