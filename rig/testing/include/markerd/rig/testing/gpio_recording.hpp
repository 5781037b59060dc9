#pragma once
// A GPIO line backend without hardware, for tests and benchmarks: one chip with
// named lines that behaves like the kernel's (lines by offset or name,
// active-low mapping, one consumer per line, edge events through a pollable
// file descriptor), and records every output edge stamped with
// CLOCK_MONOTONIC, the way a logic analyser would.
//
// Recording is lock-free and allocation-free per edge (a fixed buffer per
// output line), so a step thread driving these lines measures its own timing,
// not the recorder's.

#include <chrono>
#include <cstddef>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "markerd/rig/gpio_lines.hpp"

namespace markerd::rig {

namespace detail {
struct RecordingChip;
}

struct RecordedEdge {
  std::chrono::nanoseconds time{0};  // CLOCK_MONOTONIC when set() changed the line
  bool active = false;               // the logical value after the edge
  bool high = false;                 // the electrical level after the edge
};

class RecordingGpioBackend final : public GpioBackend {
 public:
  // A chip called `chip_name` whose line at offset i is named line_names[i].
  // Each output line keeps up to `edges_per_line` edges; later edges are
  // counted in dropped_edges().
  RecordingGpioBackend(std::string chip_name, std::vector<std::string> line_names,
                       std::size_t edges_per_line = std::size_t{1} << 18);
  ~RecordingGpioBackend() override;
  RecordingGpioBackend(const RecordingGpioBackend&) = delete;
  RecordingGpioBackend& operator=(const RecordingGpioBackend&) = delete;

  std::unique_ptr<GpioOutput> request_output(const GpioLineSpec& spec, bool initial_active,
                                             std::string_view consumer) override;
  std::unique_ptr<GpioInput> request_input(const GpioLineSpec& spec, bool edge_events,
                                           std::string_view consumer) override;

  // The test's side, by line name. Unknown names throw std::invalid_argument.

  // Sets the electrical level of an input line, as a switch (or gpio-sim's
  // pull) would; a change queues an edge event for an edge-event requester.
  void set_level(std::string_view line, bool high);
  [[nodiscard]] bool level(std::string_view line) const;
  // The output edges recorded so far, in the order they were written; the
  // initial value set by the request is not an edge.
  [[nodiscard]] std::vector<RecordedEdge> edges(std::string_view line) const;
  [[nodiscard]] std::size_t edge_count(std::string_view line) const;
  [[nodiscard]] std::size_t dropped_edges(std::string_view line) const;
  // The consumer holding the line, if requested.
  [[nodiscard]] std::optional<std::string> consumer(std::string_view line) const;

  // Called on the writing thread after each recorded output edge (line name,
  // new logical value): the test's model of the machine, e.g. a switch that
  // closes at a step position. It must be quick; it runs inside the step loop.
  // Set it before requesting any line (std::logic_error otherwise).
  using OutputHook = std::function<void(std::string_view line, bool active)>;
  void set_output_hook(OutputHook hook);

 private:
  std::shared_ptr<detail::RecordingChip> chip_;  // shared with every requested line, which may outlive the backend
};

}  // namespace markerd::rig
