#pragma once
// The system's words for an errno value, thread-safe (strerror's buffer is
// shared between threads; strerror_r's is the caller's).

#include <string>

namespace markerd {

[[nodiscard]] std::string errno_text(int error);

}  // namespace markerd
