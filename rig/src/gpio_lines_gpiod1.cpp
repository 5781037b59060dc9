// The GPIO line backend over Debian's libgpiod 1.6 (the kernel's v1 character
// device uAPI). Each requested line opens its own chip handle, so a line's
// lifetime is independent of the backend and of every other line; the kernel
// arbitrates between requesters (EBUSY), which is what tells us another
// consumer holds a line.

#include <fcntl.h>
#include <gpiod.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "markerd/base/errno_text.hpp"
#include "markerd/rig/drive.hpp"
#include "markerd/rig/gpio_lines.hpp"

namespace markerd::rig {
namespace {

struct ChipCloser {
  void operator()(gpiod_chip* chip) const noexcept { gpiod_chip_close(chip); }
};
using ChipHandle = std::unique_ptr<gpiod_chip, ChipCloser>;

bool all_digits(std::string_view s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](unsigned char c) { return std::isdigit(c) != 0; });
}

bool is_chip_name(std::string_view s) {
  constexpr std::string_view prefix = "gpiochip";
  return s.size() > prefix.size() && s.substr(0, prefix.size()) == prefix && all_digits(s.substr(prefix.size()));
}

// The /dev/gpiochipN nodes, sorted, for error messages and the label search.
std::vector<std::string> chip_names() {
  std::vector<std::string> names;
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator("/dev", ec)) {
    auto name = entry.path().filename().string();
    if (is_chip_name(name)) names.push_back(std::move(name));
  }
  std::sort(names.begin(), names.end(), [](const std::string& a, const std::string& b) {
    return a.size() != b.size() ? a.size() < b.size() : a < b;
  });
  return names;
}

// "gpiochip0 [pinctrl-bcm2711] (58 lines), gpiochip1 [raspberrypi-exp-gpio] (8 lines)"
std::string describe_chips_on_system() {
  const auto names = chip_names();
  if (names.empty()) {
    return "this system has no GPIO chips (no /dev/gpiochip*: is the GPIO driver loaded, or /dev "
           "not mounted into this container?)";
  }
  std::string list;
  for (const auto& name : names) {
    if (!list.empty()) list += ", ";
    ChipHandle chip(gpiod_chip_open_by_name(name.c_str()));
    if (chip) {
      list += fmt::format("{} [{}] ({} lines)", name, gpiod_chip_label(chip.get()), gpiod_chip_num_lines(chip.get()));
    } else {
      list += fmt::format("{} (cannot open: {})", name, errno_text(errno));
    }
  }
  return "chips on this system: " + list;
}

std::string open_failure_hint(int error) {
  if (error == EACCES || error == EPERM) {
    return "; the user running markerd needs read/write access to the chip's device node (on Raspberry Pi OS "
           "the 'gpio' group, elsewhere a udev rule)";
  }
  return "";
}

ChipHandle open_chip(const std::string& chip) {
  if (chip.empty()) throw DriveError("GPIO: no chip given (a path, a gpiochipN name or a chip label)");
  if (chip.find('/') != std::string::npos || is_chip_name(chip)) {
    const std::string path = chip.find('/') != std::string::npos ? chip : "/dev/" + chip;
    ChipHandle handle(gpiod_chip_open(path.c_str()));
    if (!handle) {
      const int error = errno;
      throw DriveError(fmt::format("GPIO chip '{}' ({}): {}{}; {}", chip, path, errno_text(error),
                                   open_failure_hint(error), describe_chips_on_system()));
    }
    return handle;
  }
  // A label: search the chips ourselves rather than through
  // gpiod_chip_open_by_label, which gives up on the first chip it cannot open.
  for (const auto& name : chip_names()) {
    ChipHandle handle(gpiod_chip_open_by_name(name.c_str()));
    if (handle && chip == gpiod_chip_label(handle.get())) return handle;
  }
  throw DriveError(fmt::format("GPIO chip labelled '{}' not found; {}", chip, describe_chips_on_system()));
}

std::string describe_chip(gpiod_chip* chip) {
  return fmt::format("{} [{}]", gpiod_chip_name(chip), gpiod_chip_label(chip));
}

// "gpiochip0 [pinctrl-bcm2711] line 17 (GPIO17)"
std::string describe_line(gpiod_chip* chip, gpiod_line* line) {
  const char* name = gpiod_line_name(line);
  return fmt::format("{} line {}{}", describe_chip(chip), gpiod_line_offset(line),
                     name != nullptr && *name != '\0' ? fmt::format(" ({})", name) : std::string());
}

gpiod_line* find_line(gpiod_chip* chip, const std::string& line) {
  if (line.empty())
    throw DriveError(fmt::format("GPIO {}: no line given (an offset or a line name)", describe_chip(chip)));
  if (all_digits(line)) {
    unsigned long offset = 0;
    const auto parsed = std::from_chars(line.data(), line.data() + line.size(), offset);
    const unsigned lines = gpiod_chip_num_lines(chip);
    if (parsed.ec != std::errc() || offset >= lines) {
      throw DriveError(fmt::format("GPIO {}: line offset {} out of range: the chip has {} lines (0 to {})",
                                   describe_chip(chip), offset, lines, lines - 1));
    }
    gpiod_line* handle = gpiod_chip_get_line(chip, static_cast<unsigned>(offset));
    if (handle == nullptr) {
      throw DriveError(fmt::format("GPIO {}: line {}: {}", describe_chip(chip), offset, errno_text(errno)));
    }
    return handle;
  }
  gpiod_line* handle = gpiod_chip_find_line(chip, line.c_str());
  if (handle == nullptr) {
    const int error = errno;
    if (error == ENOENT) {
      throw DriveError(fmt::format("GPIO {}: no line named '{}' (gpioinfo {} lists the names)", describe_chip(chip),
                                   line, gpiod_chip_name(chip)));
    }
    throw DriveError(fmt::format("GPIO {}: looking up line '{}': {}", describe_chip(chip), line, errno_text(error)));
  }
  return handle;
}

[[noreturn]] void throw_request_failure(gpiod_line* line, const std::string& description, int error) {
  if (error == EBUSY) {
    // The kernel refuses a second requester; the line info names the holder
    // unless the kernel itself holds it (a hog, a driver) without a label.
    std::string holder = "held by the kernel or another process (no consumer name)";
    if (gpiod_line_update(line) == 0) {
      const char* consumer = gpiod_line_consumer(line);
      if (consumer != nullptr && *consumer != '\0') holder = fmt::format("held by consumer '{}'", consumer);
    }
    throw DriveError(fmt::format("GPIO {}: busy, {}", description, holder));
  }
  throw DriveError(fmt::format("GPIO {}: request failed: {}", description, errno_text(error)));
}

int request_flags(const GpioLineSpec& spec) { return spec.active_low ? GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW : 0; }

class Gpiod1Output final : public GpioOutput {
 public:
  Gpiod1Output(ChipHandle chip, gpiod_line* line, std::string description)
      : chip_(std::move(chip)), line_(line), description_(std::move(description)) {}

  void set(bool active) override {
    if (gpiod_line_set_value(line_, active ? 1 : 0) < 0) {
      throw DriveError(fmt::format("GPIO {}: write failed: {}", description_, errno_text(errno)));
    }
  }

 private:
  ChipHandle chip_;  // closing the chip releases the line
  gpiod_line* line_;
  std::string description_;
};

class Gpiod1Input final : public GpioInput {
 public:
  Gpiod1Input(ChipHandle chip, gpiod_line* line, std::string description, bool edge_events)
      : chip_(std::move(chip)), line_(line), description_(std::move(description)) {
    if (edge_events) {
      event_fd_ = gpiod_line_event_get_fd(line_);
      // read_event must never block: the caller polls the fd and drains it.
      const int flags = event_fd_ < 0 ? -1 : fcntl(event_fd_, F_GETFL);
      if (flags < 0 || fcntl(event_fd_, F_SETFL, flags | O_NONBLOCK) < 0) {
        throw DriveError(
            fmt::format("GPIO {}: cannot set up its event file descriptor: {}", description_, errno_text(errno)));
      }
    }
  }

  bool get() override {
    const int value = gpiod_line_get_value(line_);
    if (value < 0) throw DriveError(fmt::format("GPIO {}: read failed: {}", description_, errno_text(errno)));
    return value != 0;
  }

  [[nodiscard]] int event_fd() const override { return event_fd_; }

  std::optional<GpioEdgeEvent> read_event() override {
    if (event_fd_ < 0) return std::nullopt;
    gpiod_line_event event{};
    if (gpiod_line_event_read(line_, &event) < 0) {
      if (errno == EAGAIN) return std::nullopt;
      throw DriveError(fmt::format("GPIO {}: reading an edge event failed: {}", description_, errno_text(errno)));
    }
    // With both edges requested the kernel reads the line's logical level to
    // tell the edges apart, so "rising" means "became active" on active-low
    // lines too.
    return GpioEdgeEvent{event.event_type == GPIOD_LINE_EVENT_RISING_EDGE,
                         std::chrono::seconds(event.ts.tv_sec) + std::chrono::nanoseconds(event.ts.tv_nsec)};
  }

 private:
  ChipHandle chip_;
  gpiod_line* line_;
  std::string description_;
  int event_fd_ = -1;  // owned by the line request
};

class Gpiod1Backend final : public GpioBackend {
 public:
  std::unique_ptr<GpioOutput> request_output(const GpioLineSpec& spec, bool initial_active,
                                             std::string_view consumer) override {
    ChipHandle chip = open_chip(spec.chip);
    gpiod_line* line = find_line(chip.get(), spec.line);
    std::string description = describe_line(chip.get(), line);
    const std::string consumer_name(consumer);
    if (gpiod_line_request_output_flags(line, consumer_name.c_str(), request_flags(spec), initial_active ? 1 : 0) < 0) {
      throw_request_failure(line, description, errno);
    }
    return std::make_unique<Gpiod1Output>(std::move(chip), line, std::move(description));
  }

  std::unique_ptr<GpioInput> request_input(const GpioLineSpec& spec, bool edge_events,
                                           std::string_view consumer) override {
    ChipHandle chip = open_chip(spec.chip);
    gpiod_line* line = find_line(chip.get(), spec.line);
    std::string description = describe_line(chip.get(), line);
    const std::string consumer_name(consumer);
    const int result =
        edge_events ? gpiod_line_request_both_edges_events_flags(line, consumer_name.c_str(), request_flags(spec))
                    : gpiod_line_request_input_flags(line, consumer_name.c_str(), request_flags(spec));
    if (result < 0) throw_request_failure(line, description, errno);
    return std::make_unique<Gpiod1Input>(std::move(chip), line, std::move(description), edge_events);
  }
};

}  // namespace

std::unique_ptr<GpioBackend> make_gpiod1_backend() { return std::make_unique<Gpiod1Backend>(); }

}  // namespace markerd::rig
