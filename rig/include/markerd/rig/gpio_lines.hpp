#pragma once
// GPIO line access behind a small interface, so that the stepper does not
// depend on one libgpiod API: Debian's libgpiod 1.6 backend now, a libgpiod 2
// backend later, and a recording backend for the tests and benchmarks
// (rig/testing/, markerd/rig/testing/gpio_recording.hpp) that stamps every
// output edge and lets them drive the inputs.
//
// Values are logical: true = active. Active-low lines are inverted by the
// backend, so the stepper never sees electrical levels.
//
// Every failure is a DriveError (drive.hpp) naming the chip, the line and the
// cause. A returned line is released when its object is destroyed; it does not
// depend on the backend object that made it.

#include <chrono>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

namespace markerd::rig {

struct GpioLineSpec {
  std::string chip;  // "/dev/gpiochip0" (a path), "gpiochip0" (a name), or the chip's label
  std::string line;  // the line's offset ("17", all digits) or its name ("STEP_RAIL")
  bool active_low = false;
};

struct GpioEdgeEvent {
  bool active = false;  // the logical value after the edge
  // The kernel's timestamp of the edge (CLOCK_MONOTONIC since Linux 5.7,
  // CLOCK_REALTIME before it: compare only event to event).
  std::chrono::nanoseconds timestamp{0};
};

class GpioOutput {
 public:
  virtual ~GpioOutput() = default;
  // Drives the line. Not safe to call from two threads at once on one line:
  // the owner serialises writers. Throws DriveError naming the line.
  virtual void set(bool active) = 0;
};

class GpioInput {
 public:
  virtual ~GpioInput() = default;
  [[nodiscard]] virtual bool get() = 0;  // the current logical level; throws DriveError
  // A file descriptor that polls readable (POLLIN) while edge events are
  // pending (requested with edge events only); -1 otherwise.
  [[nodiscard]] virtual int event_fd() const = 0;
  // The next pending edge event, or nothing when none is pending (never blocks).
  virtual std::optional<GpioEdgeEvent> read_event() = 0;
};

class GpioBackend {
 public:
  virtual ~GpioBackend() = default;
  // Requests a line for this process; fails (DriveError naming chip and line)
  // when the chip or the line does not exist or another consumer holds it.
  virtual std::unique_ptr<GpioOutput> request_output(const GpioLineSpec& spec, bool initial_active,
                                                     std::string_view consumer) = 0;
  // With edge_events, both edges are reported (event_fd, read_event).
  virtual std::unique_ptr<GpioInput> request_input(const GpioLineSpec& spec, bool edge_events,
                                                   std::string_view consumer) = 0;
};

// Debian's libgpiod 1.6 (character device, v1 uAPI).
std::unique_ptr<GpioBackend> make_gpiod1_backend();

}  // namespace markerd::rig
