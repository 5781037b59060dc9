#include "markerd/daemon/control/camera_commands.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <vector>

#include "markerd/daemon/capture/camera_controls.hpp"

namespace markerd::daemon {

namespace {

using nlohmann::json;

// The controls, or why they cannot be read, with what the capture loop
// knows of the camera (it is waiting for a camera unplugged, ...).
std::vector<CameraControlInfo> read_controls(CaptureSource& source, const CaptureLoop& capture) {
  try {
    return source.read_controls();
  } catch (const CaptureError& e) {
    const CaptureStatus status = capture.status();
    std::string why = e.what();
    if (status.state != CaptureState::streaming) {
      why += fmt::format(" (the camera is {}{})", to_string(status.state),
                         status.last_error.empty() ? std::string() : ": " + status.last_error);
    }
    throw ControlError(why);
  }
}

std::vector<std::string> names_argument(const json& request) {
  std::vector<std::string> names;
  const auto it = request.find("names");
  if (it == request.end() || it->is_null()) return names;
  const auto refuse = [&] {
    return ControlError(fmt::format("argument 'names' must be a list of control names, got {} ({})",
                                    json_type_name(*it), it->dump(-1, ' ', false, json::error_handler_t::replace)));
  };
  if (!it->is_array()) throw refuse();
  for (const auto& name : *it) {
    if (!name.is_string()) throw refuse();
    names.push_back(name.get<std::string>());
  }
  return names;
}

std::vector<ControlAssignment> controls_argument(const json& request) {
  const auto it = request.find("controls");
  if (it == request.end() || it->is_null()) {
    throw ControlError(R"(argument 'controls' is missing: the controls to set, e.g. {"gain": 200})");
  }
  if (!it->is_object() || it->empty()) {
    throw ControlError(fmt::format(R"(argument 'controls' must be an object of control names and values, e.g. )"
                                   R"({{"gain": 200}}, got {} ({}))",
                                   json_type_name(*it), it->dump(-1, ' ', false, json::error_handler_t::replace)));
  }
  std::vector<ControlAssignment> assignments;
  for (const auto& [name, value] : it->items()) {
    try {
      assignments.push_back({name, control_input_from_json(value)});
    } catch (const ControlValueError& e) {
      throw ControlError(fmt::format("{}: {}; nothing was changed", name, e.what()));
    }
  }
  return assignments;
}

std::string change_text(const ControlChange& change) {
  return fmt::format("{} {} -> {}", change.control.name,
                     change.old_value ? value_text(change.control, *change.old_value) : std::string("(unknown)"),
                     value_text(change.control, change.new_value));
}

}  // namespace

void register_camera_commands(ControlServer& server, CaptureSource& source, const CaptureLoop& capture,
                              ControlChangeRecorder record) {
  server.register_command(
      "camera.get",
      [&source, &capture](const json& request) {
        expect_arguments(request, {"names"});
        const std::vector<std::string> names = names_argument(request);
        const std::vector<CameraControlInfo> controls = read_controls(source, capture);
        json list = json::array();
        if (names.empty()) {
          for (const auto& c : controls) list.push_back(to_json(c));
        }
        for (const auto& name : names) {
          const auto it = std::find_if(controls.begin(), controls.end(), [&](const auto& c) { return c.name == name; });
          if (it == controls.end()) {
            std::string known;
            for (const auto& c : controls) known += fmt::format("{}{}", known.empty() ? "" : ", ", c.name);
            throw ControlError(fmt::format("{} has no control '{}' (its controls: {})", source.name(), name,
                                           known.empty() ? "none" : known));
          }
          list.push_back(to_json(*it));
        }
        return json{{"source", source.name()}, {"controls", std::move(list)}};
      },
      "the camera's controls (names: only those): value, min, max, step, default, menu items, flags");
  server.register_command(
      "camera.set",
      [&source, &capture, record = std::move(record)](const json& request) {
        expect_arguments(request, {"controls"});
        const std::vector<ControlAssignment> assignments = controls_argument(request);
        (void)read_controls(source, capture);  // a camera that is not open is refused in its words
        std::vector<ControlChange> changes;
        try {
          changes = set_camera_controls(source, assignments);
        } catch (const ControlValueError& e) {
          spdlog::info("camera {}: camera.set refused: {}", source.name(), e.what());
          throw ControlError(e.what());
        }
        json changed = json::array();
        for (const auto& change : changes) {
          const std::string text = change_text(change);
          spdlog::info("camera {}: control {} (camera.set)", source.name(), text);
          if (record) record(text);
          changed.push_back({{"name", change.control.name},
                             {"old", change.old_value ? to_json(*change.old_value) : json(nullptr)},
                             {"new", to_json(change.new_value)}});
        }
        // As the device reports them now.
        json now = json::array();
        for (const auto& c : read_controls(source, capture)) {
          if (std::any_of(changes.begin(), changes.end(), [&](const auto& x) { return x.control.name == c.name; })) {
            now.push_back(to_json(c));
          }
        }
        return json{{"source", source.name()}, {"changed", std::move(changed)}, {"controls", std::move(now)}};
      },
      "sets camera controls (controls: {name: value, ...}), all or none, each checked against its range");
}

}  // namespace markerd::daemon
