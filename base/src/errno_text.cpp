#include "markerd/base/errno_text.hpp"

#include <cstring>

namespace markerd {

std::string errno_text(int error) {
  char buffer[256];
  // GNU strerror_r: returns the text, in the buffer or a static string.
  return strerror_r(error, buffer, sizeof buffer);
}

}  // namespace markerd
