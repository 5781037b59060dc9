#pragma once
#include <optional>
#include <span>
#include <string_view>

namespace markerd::detector {

// Every marker family the project detects, prints and renders. frame8 is the
// thesis's frame marker (docs/frame-marker.md); the others are comparison peers.
enum class Family { frame8, aruco4x4_50, tag36h11 };

struct FamilyInfo {
  Family family;
  std::string_view name;  // as on the command line and in logs
  int id_count;           // valid ids are 0 .. id_count-1
  // Side of the printed square that "marker size" refers to, in grid cells,
  // and the full grid the pattern is drawn on (cells). frame8: size = the
  // outer edge (10 cells). ArUco and AprilTag: size = the outer black border;
  // they need one white cell of quiet zone outside it.
  int size_cells;
  int quiet_zone_cells;
  // The ids a detector reports with its default options: frame8 leaves out
  // 0 and 255, whose rings have no structure (see Frame8Options::uniform_ids).
  int first_default_id;
  int last_default_id;
  [[nodiscard]] constexpr int default_id_count() const { return last_default_id - first_default_id + 1; }
};

std::span<const FamilyInfo> all_families();
const FamilyInfo& family_info(Family family);
std::optional<Family> family_from_name(std::string_view name);

}  // namespace markerd::detector
