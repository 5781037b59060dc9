// markerctl camera get|set: the controls of the camera markerd streams from,
// read and set at run time through its control socket (camera.get,
// camera.set; docs/control.md#camera). markerd checks every value against
// the control's range and sets all or none; this side only turns NAME=VALUE
// words into the request and the reply into lines.

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "cmd_daemon.hpp"
#include "common.hpp"

namespace markerctl {
namespace {

using nlohmann::json;

struct CameraOptions {
  std::string socket;
  std::vector<std::string> words;  // get: names; set: NAME=VALUE
  bool json = false;
};

// VALUE as JSON: true or false, a whole number, a number, or else a word (a
// menu item's name). markerd decides whether the control takes it.
json value_of(const std::string& text) {
  if (text == "true") return true;
  if (text == "false") return false;
  std::int64_t whole = 0;
  if (const auto [end, error] = std::from_chars(text.data(), text.data() + text.size(), whole);
      error == std::errc{} && end == text.data() + text.size()) {
    return whole;
  }
  double number = 0;
  if (const auto [end, error] = std::from_chars(text.data(), text.data() + text.size(), number);
      error == std::errc{} && end == text.data() + text.size() && std::isfinite(number)) {
    return number;
  }
  return text;
}

json assignments(const std::vector<std::string>& words) {
  json controls = json::object();
  for (const std::string& word : words) {
    const auto equals = word.find('=');
    if (equals == std::string::npos) {
      throw usage_error("camera set", fmt::format("'{}' is not NAME=VALUE (e.g. gain=200)", word));
    }
    const std::string name = word.substr(0, equals);
    const std::string value = word.substr(equals + 1);
    if (name.empty()) throw usage_error("camera set", fmt::format("'{}' has no control name before '='", word));
    if (value.empty()) throw usage_error("camera set", fmt::format("'{}' has no value after '='", word));
    if (controls.contains(name)) throw usage_error("camera set", fmt::format("{} is given twice", name));
    controls[name] = value_of(value);
  }
  return controls;
}

std::string text_of(const json& value) {
  if (value.is_null()) return "?";
  if (value.is_string()) return value.get<std::string>();
  return value.dump(-1, ' ', false, json::error_handler_t::replace);
}

// A value with its menu item's name where the control has a menu.
std::string value_text(const json& control, const json& value) {
  std::string text = text_of(value);
  if (control.contains("menu") && value.is_number_integer()) {
    for (const json& item : control["menu"]) {
      if (item.value("index", std::int64_t{-1}) == value.get<std::int64_t>()) {
        text += fmt::format(" ({})", item.value("name", std::string()));
      }
    }
  }
  return text;
}

std::string control_line(const json& c) {
  std::string details = c.value("range", std::string());
  if (const json& d = c.value("default", json()); !d.is_null()) {
    details += fmt::format("{}default {}", details.empty() ? "" : "; ", value_text(c, d));
  }
  std::string flags;
  for (const json& f : c.value("flags", json::array())) flags += (flags.empty() ? "" : ", ") + text_of(f);
  if (!flags.empty()) details += fmt::format(" [{}]", flags);
  return fmt::format("  {:<30} {:<7} {:<18} {}", text_of(c.value("name", json())), text_of(c.value("type", json())),
                     value_text(c, c.value("value", json())), details);
}

int run_get(const CameraOptions& o) {
  DaemonConnection daemon(o.socket, "camera get");
  json request{{"cmd", "camera.get"}};
  if (!o.words.empty()) request["names"] = o.words;
  const json reply = daemon.call(request);
  if (o.json) {
    std::cout << json_line(nlohmann::ordered_json(reply)) << '\n';
    return 0;
  }
  std::cout << text_of(reply.value("source", json())) << '\n';
  const json controls = reply.value("controls", json::array());
  if (controls.empty()) std::cout << "  no controls\n";
  for (const json& c : controls) std::cout << control_line(c) << '\n';
  return 0;
}

int run_set(const CameraOptions& o) {
  const json controls = assignments(o.words);
  DaemonConnection daemon(o.socket, "camera set");
  const json reply = daemon.call({{"cmd", "camera.set"}, {"controls", controls}});
  if (o.json) {
    std::cout << json_line(nlohmann::ordered_json(reply)) << '\n';
    return 0;
  }
  const json now = reply.value("controls", json::array());
  for (const json& change : reply.value("changed", json::array())) {
    const std::string name = text_of(change.value("name", json()));
    json control = json::object();
    for (const json& c : now) {
      if (c.value("name", std::string()) == name) control = c;
    }
    std::cout << fmt::format("{}: {} -> {}\n", name, value_text(control, change.value("old", json())),
                             value_text(control, change.value("new", json())));
  }
  return 0;
}

}  // namespace

void add_camera_command(CLI::App& parent, Commands& commands) {
  const char* socket_help = "markerd's control socket (default: $MARKERD_SOCKET, else /run/markerd/control.sock)";
  CLI::App* camera = parent.add_subcommand(
      "camera", "Read and set the controls of the camera markerd streams from (exposure, gain, ...)");
  camera->require_subcommand(1);
  camera->footer(
      "Talks to a running markerd over its control socket (docs/control.md#camera); markerctl cameras lists\n"
      "every camera of the machine without markerd. A value set lasts until markerd stops (a camera that\n"
      "reopens gets it again); the config file is not changed.");

  auto get_options = std::make_shared<CameraOptions>();
  CLI::App* get = camera->add_subcommand(
      "get", "Each control (or those NAMEd) with its value, range, step, default, menu items and flags");
  get->add_option("name", get_options->words, "Only these controls")->type_name("NAME");
  get->add_option("--socket", get_options->socket, socket_help)->type_name("PATH");
  get->add_flag("--json", get_options->json, "camera.get's reply as one JSON object");
  commands.push_back({get, [get_options] { return run_get(*get_options); }});

  auto set_options = std::make_shared<CameraOptions>();
  CLI::App* set = camera->add_subcommand(
      "set", "Set controls: all or none, each checked against its range; prints each old and new value");
  set->add_option("assignment", set_options->words, "A control and its value: gain=200, auto_exposure=\"Manual Mode\"")
      ->type_name("NAME=VALUE")
      ->required();
  set->add_option("--socket", set_options->socket, socket_help)->type_name("PATH");
  set->add_flag("--json", set_options->json, "camera.set's reply as one JSON object");
  set->footer(
      "VALUE is true or false, a number, or a menu item's name (or its number). markerd refuses the whole\n"
      "set, naming the control and what it takes, for an unknown control, a value out of its range or off its\n"
      "steps, a read-only control, or one an automatic mode holds (set that mode in the same command).\n"
      "Every change is in markerd's log and in the events of the sweep run going on.");
  commands.push_back({set, [set_options] { return run_set(*set_options); }});
}

}  // namespace markerctl
