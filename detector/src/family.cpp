#include "markerd/detector/family.hpp"

#include <array>
#include <stdexcept>

namespace markerd::detector {
namespace {
constexpr std::array<FamilyInfo, 3> families{{
    {Family::frame8, "frame8", 256, 10, 0, 1, 254},
    {Family::aruco4x4_50, "aruco4x4_50", 50, 6, 1, 0, 49},
    {Family::tag36h11, "tag36h11", 587, 8, 1, 0, 586},
}};
}  // namespace

std::span<const FamilyInfo> all_families() { return families; }

const FamilyInfo& family_info(Family family) {
  for (const auto& info : families) {
    if (info.family == family) return info;
  }
  throw std::logic_error("family_info: unknown family");
}

std::optional<Family> family_from_name(std::string_view name) {
  for (const auto& info : families) {
    if (info.name == name) return info.family;
  }
  return std::nullopt;
}

}  // namespace markerd::detector
