#pragma once
// Random (version 4) UUIDs, "3f0c2a4e-9b1d-4c8e-a2f1-6d5e4b3a2c1f": the uids
// Bluesky's event model gives its documents (sweep/documents.hpp), made from
// the kernel's random bytes so that no two markerds, nor two runs of one,
// ever make the same.

#include <string>

namespace markerd {

// std::runtime_error when the kernel gives no random bytes (it does once
// its pool is initialised, early in boot).
[[nodiscard]] std::string new_uuid4();

}  // namespace markerd
