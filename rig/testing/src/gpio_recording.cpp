#include "markerd/rig/testing/gpio_recording.hpp"

#include <sys/eventfd.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <cstdint>
#include <cstring>
#include <ctime>
#include <deque>
#include <mutex>
#include <stdexcept>

#include <fmt/format.h>

#include "markerd/rig/drive.hpp"

namespace markerd::rig {
namespace {

std::int64_t monotonic_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return std::int64_t{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec;
}

// One recorded edge. Writers reserve a slot with a fetch_add and publish it
// with `ready`, so several threads may write one line (the enable line is
// written by the control thread and by emergency stops) without a lock.
struct Slot {
  std::atomic<bool> ready{false};
  std::int64_t time_ns = 0;
  bool active = false;
  bool high = false;
};

}  // namespace

namespace detail {

struct RecordingChip {
  struct Line {
    std::string name;
    unsigned offset = 0;
    std::atomic<bool> high{false};  // the electrical level
    // Guarded by Chip::mutex.
    std::optional<std::string> consumer;
    bool output = false;
    bool active_low = false;
    int event_fd = -1;  // an eventfd, while an edge-event requester holds the line
    std::deque<GpioEdgeEvent> events;
    // The output recording: allocated on the first output request, then kept.
    std::unique_ptr<Slot[]> slots;
    std::atomic<std::size_t> reserved{0};
    std::atomic<std::size_t> dropped{0};
  };

  std::string name;
  std::size_t edges_per_line = 0;
  std::vector<std::unique_ptr<Line>> lines;
  mutable std::mutex mutex;
  RecordingGpioBackend::OutputHook hook;  // immutable once a line was requested
  bool requested_any = false;

  [[nodiscard]] std::string describe(const Line& line) const {
    return fmt::format("{} [recording] line {} ({})", name, line.offset, line.name);
  }

  Line& resolve(const GpioLineSpec& spec) {
    if (spec.chip != name && spec.chip != "/dev/" + name) {
      throw DriveError(fmt::format("GPIO chip '{}' not found; chips on this system: {} [recording] ({} lines)",
                                   spec.chip, name, lines.size()));
    }
    unsigned offset = 0;
    const char* end = spec.line.data() + spec.line.size();
    if (!spec.line.empty() && std::from_chars(spec.line.data(), end, offset).ptr == end) {
      if (offset >= lines.size()) {
        throw DriveError(
            fmt::format("GPIO {} [recording]: line offset {} out of range: the chip has {} lines (0 to {})", name,
                        offset, lines.size(), lines.size() - 1));
      }
      return *lines[offset];
    }
    for (auto& line : lines) {
      if (line->name == spec.line) return *line;
    }
    throw DriveError(fmt::format("GPIO {} [recording]: no line named '{}'", name, spec.line));
  }

  Line& by_name(std::string_view line_name) const {
    for (const auto& line : lines) {
      if (line->name == line_name) return *line;
    }
    throw std::invalid_argument(fmt::format("recording GPIO chip {}: no line named '{}'", name, line_name));
  }

  // Takes the line for `consumer`, as the kernel would: one requester at a time.
  void claim(Line& line, std::string_view consumer) {
    if (line.consumer)
      throw DriveError(fmt::format("GPIO {}: busy, held by consumer '{}'", describe(line), *line.consumer));
    line.consumer = std::string(consumer);
    requested_any = true;
  }
};

}  // namespace detail

namespace {

using Chip = detail::RecordingChip;

class RecordingOutput final : public GpioOutput {
 public:
  RecordingOutput(std::shared_ptr<Chip> chip, Chip::Line& line, bool active_low)
      : chip_(std::move(chip)), line_(line), active_low_(active_low) {}

  ~RecordingOutput() override {
    const std::lock_guard lock(chip_->mutex);
    line_.consumer.reset();
  }

  void set(bool active) override {
    const bool high = active != active_low_;
    if (line_.high.exchange(high) == high) return;  // no edge
    const std::size_t index = line_.reserved.fetch_add(1, std::memory_order_relaxed);
    if (index < chip_->edges_per_line) {
      Slot& slot = line_.slots[index];
      slot.time_ns = monotonic_ns();
      slot.active = active;
      slot.high = high;
      slot.ready.store(true, std::memory_order_release);
    } else {
      line_.dropped.fetch_add(1, std::memory_order_relaxed);
    }
    if (chip_->hook) chip_->hook(line_.name, active);
  }

 private:
  std::shared_ptr<Chip> chip_;
  Chip::Line& line_;
  bool active_low_;
};

class RecordingInput final : public GpioInput {
 public:
  RecordingInput(std::shared_ptr<Chip> chip, Chip::Line& line, bool active_low)
      : chip_(std::move(chip)), line_(line), active_low_(active_low) {}

  ~RecordingInput() override {
    const std::lock_guard lock(chip_->mutex);
    line_.consumer.reset();
    if (line_.event_fd >= 0) close(line_.event_fd);
    line_.event_fd = -1;
    line_.events.clear();
  }

  bool get() override { return line_.high.load() != active_low_; }

  [[nodiscard]] int event_fd() const override {
    const std::lock_guard lock(chip_->mutex);
    return line_.event_fd;
  }

  std::optional<GpioEdgeEvent> read_event() override {
    const std::lock_guard lock(chip_->mutex);
    if (line_.event_fd < 0) return std::nullopt;
    std::optional<GpioEdgeEvent> event;
    if (!line_.events.empty()) {
      event = line_.events.front();
      line_.events.pop_front();
    }
    // The fd polls readable exactly while events are queued: drain its
    // counter once the queue is empty (under the lock that set_level takes).
    if (line_.events.empty()) {
      std::uint64_t count = 0;
      [[maybe_unused]] const auto ignored = ::read(line_.event_fd, &count, sizeof count);
    }
    return event;
  }

 private:
  std::shared_ptr<Chip> chip_;
  Chip::Line& line_;
  bool active_low_;
};

}  // namespace

RecordingGpioBackend::RecordingGpioBackend(std::string chip_name, std::vector<std::string> line_names,
                                           std::size_t edges_per_line)
    : chip_(std::make_shared<detail::RecordingChip>()) {
  chip_->name = std::move(chip_name);
  chip_->edges_per_line = edges_per_line;
  for (auto& name : line_names) {
    auto line = std::make_unique<Chip::Line>();
    line->name = std::move(name);
    line->offset = static_cast<unsigned>(chip_->lines.size());
    chip_->lines.push_back(std::move(line));
  }
}

RecordingGpioBackend::~RecordingGpioBackend() = default;

std::unique_ptr<GpioOutput> RecordingGpioBackend::request_output(const GpioLineSpec& spec, bool initial_active,
                                                                 std::string_view consumer) {
  const std::lock_guard lock(chip_->mutex);
  Chip::Line& line = chip_->resolve(spec);
  chip_->claim(line, consumer);
  line.output = true;
  line.active_low = spec.active_low;
  if (!line.slots) line.slots = std::make_unique<Slot[]>(chip_->edges_per_line);
  line.high.store(initial_active != spec.active_low);
  return std::make_unique<RecordingOutput>(chip_, line, spec.active_low);
}

std::unique_ptr<GpioInput> RecordingGpioBackend::request_input(const GpioLineSpec& spec, bool edge_events,
                                                               std::string_view consumer) {
  const std::lock_guard lock(chip_->mutex);
  Chip::Line& line = chip_->resolve(spec);
  chip_->claim(line, consumer);
  line.output = false;
  line.active_low = spec.active_low;
  if (edge_events) {
    line.event_fd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (line.event_fd < 0) {
      line.consumer.reset();
      throw DriveError(fmt::format("GPIO {}: eventfd: {}", chip_->describe(line), std::strerror(errno)));
    }
  }
  return std::make_unique<RecordingInput>(chip_, line, spec.active_low);
}

void RecordingGpioBackend::set_level(std::string_view line_name, bool high) {
  const std::lock_guard lock(chip_->mutex);
  Chip::Line& line = chip_->by_name(line_name);
  if (line.output && line.consumer) {
    throw std::logic_error(
        fmt::format("recording GPIO: line '{}' is an output held by '{}'", line_name, *line.consumer));
  }
  if (line.high.exchange(high) == high || line.event_fd < 0) return;
  line.events.push_back(GpioEdgeEvent{high != line.active_low, std::chrono::nanoseconds(monotonic_ns())});
  const std::uint64_t one = 1;
  [[maybe_unused]] const auto ignored = ::write(line.event_fd, &one, sizeof one);
}

bool RecordingGpioBackend::level(std::string_view line) const { return chip_->by_name(line).high.load(); }

std::vector<RecordedEdge> RecordingGpioBackend::edges(std::string_view line_name) const {
  const Chip::Line& line = chip_->by_name(line_name);
  std::vector<RecordedEdge> result;
  if (!line.slots) return result;
  const std::size_t count = std::min(line.reserved.load(std::memory_order_acquire), chip_->edges_per_line);
  result.reserve(count);
  for (std::size_t i = 0; i < count; ++i) {
    const Slot& slot = line.slots[i];
    if (!slot.ready.load(std::memory_order_acquire)) break;  // still being written
    result.push_back(RecordedEdge{std::chrono::nanoseconds(slot.time_ns), slot.active, slot.high});
  }
  return result;
}

std::size_t RecordingGpioBackend::edge_count(std::string_view line) const {
  const Chip::Line& state = chip_->by_name(line);
  return std::min(state.reserved.load(std::memory_order_acquire), chip_->edges_per_line);
}

std::size_t RecordingGpioBackend::dropped_edges(std::string_view line) const {
  return chip_->by_name(line).dropped.load();
}

std::optional<std::string> RecordingGpioBackend::consumer(std::string_view line) const {
  const std::lock_guard lock(chip_->mutex);
  return chip_->by_name(line).consumer;
}

void RecordingGpioBackend::set_output_hook(OutputHook hook) {
  const std::lock_guard lock(chip_->mutex);
  if (chip_->requested_any) throw std::logic_error("recording GPIO: set the output hook before requesting lines");
  chip_->hook = std::move(hook);
}

}  // namespace markerd::rig
