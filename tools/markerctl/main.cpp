// markerctl: the command line of markerd. Each subcommand registers itself
// (add_*_command) with its options and a run function; main() parses, runs
// the chosen one and turns every failure into one line on stderr,
// "markerctl: <what>: <why>", with exit 2 for usage errors and 1 for the rest.

// First, before anything includes <string>: g++ 12 at -O2 reports a false
// "potential null pointer dereference" in std::string inlined from
// CLI::App's constructor (CLI::detail::split), and the warning is classified
// by the location of the header line, which only this region can cover.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wnull-dereference"
#include <CLI/CLI.hpp>
#pragma GCC diagnostic pop

#include <fmt/format.h>

#include <exception>
#include <iostream>
#include <opencv2/core.hpp>
#include <opencv2/core/utils/logger.hpp>

#include "cmd_daemon.hpp"
#include "cmd_snapshot.hpp"
#include "common.hpp"
#include "did_you_mean.hpp"
#include "markerd/detector/board.hpp"
#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/detector/print.hpp"

#ifndef MARKERD_VERSION
#define MARKERD_VERSION "unknown"
#endif

namespace {

void print_error(const std::string& context, const std::string& why) {
  std::cout.flush();
  if (context.empty()) {
    std::cerr << fmt::format("markerctl: {}\n", why);
  } else {
    std::cerr << fmt::format("markerctl: {}: {}\n", context, why);
  }
}

int run(const markerctl::Command& command) {
  const std::string name = command.app->get_name();
  try {
    return command.run();
  } catch (const markerctl::CommandError& e) {
    print_error(e.context(), e.what());
    return e.exit_code();
  } catch (const markerd::detector::CameraModelError& e) {
    print_error(name, e.what());
  } catch (const markerd::detector::PrintError& e) {
    print_error(name, e.what());
  } catch (const markerd::detector::DetectorError& e) {
    print_error(name, e.what());
  } catch (const markerd::detector::BoardError& e) {
    print_error(name, e.what());
  } catch (const cv::Exception& e) {
    print_error(name, fmt::format("OpenCV: {}", e.err.empty() ? std::string(e.what()) : e.err));
  } catch (const std::exception& e) {
    print_error(name, e.what());
  }
  return markerctl::exit_runtime;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "markerctl: the command line of markerd. Prints frame markers, renders camera views of them,\n"
      "detects markers in images, evaluates the detectors on rendered scenes, calibrates a camera and brings up a "
      "rig.\n"
      "Families: " +
          markerctl::family_names() + ". Lengths take a unit: 80mm, 8cm, 0.08m, 3.15in.",
      "markerctl"};
  app.require_subcommand(1);
  app.set_version_flag("--version", fmt::format("markerctl {}", MARKERD_VERSION));
  app.get_formatter()->column_width(34);
  app.footer(
      "Examples:\n"
      "  markerctl marker --id 165 --size 80mm -o marker.pdf\n"
      "  markerctl render --dist 0.95 --yaw 30 -o frame.png\n"
      "  markerctl detect --camera config/cameras/thesis-640x480.yaml --size 0.08 frame.png\n"
      "  markerctl evaluate --family frame8\n"
      "  markerctl rig --config config/rig-sim.toml move --home --rail 250mm --turntable 30deg\n"
      "  markerctl cameras\n"
      "  markerctl camera set gain=200   (markerd's camera, at run time)\n"
      "  markerctl status                  (and detections, call, rig without --config: a running markerd)\n"
      "  markerctl snapshot --annotate -o aim.png\n"
      "  markerctl sweep start --wait config/plans/thesis.toml\n"
      "  markerctl report /var/lib/markerd/runs/RUN\n"
      "  markerctl calibrate --rig /var/lib/markerd/runs/RUN -o camera.yaml --rig-out rig-geometry.toml\n"
      "  markerctl calibrate --board board.toml views/*.png -o camera.yaml --ros camera-ros.yaml\n"
      "Run 'markerctl <command> --help' for a command's options. Exit status: 0 on success,\n"
      "1 when something failed while running, 2 for a mistake on the command line.");

  // OpenCV logs its own view of a failure (a camera file it cannot open, an
  // image it cannot decode); markerctl reports each once, in its own words.
  cv::utils::logging::setLogLevel(cv::utils::logging::LOG_LEVEL_SILENT);

  markerctl::Commands commands;
  markerctl::add_marker_command(app, commands);
  markerctl::add_render_command(app, commands);
  markerctl::add_detect_command(app, commands);
  markerctl::add_evaluate_command(app, commands);
  markerctl::add_rig_command(app, commands);
  markerctl::add_cameras_command(app, commands);
  markerctl::add_camera_command(app, commands);
  markerctl::add_daemon_commands(app, commands);
  markerctl::add_snapshot_command(app, commands);
  markerctl::add_sweep_command(app, commands);
  markerctl::add_report_command(app, commands);
  markerctl::add_calibrate_command(app, commands);

  if (argc <= 1) {
    std::cerr << app.help();
    print_error("",
                "no command given (marker, render, detect, evaluate, rig, cameras, camera, status, detections, "
                "call, snapshot, sweep, report or calibrate)");
    return markerctl::exit_usage;
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::Success& e) {  // --help, --help-all, --version
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    // A word markerctl does not know is named first, with the names it may
    // have meant: CLI11 would report whatever rule it checks first instead.
    if (const auto unknown = markerctl::find_unknown_name(app, std::vector<std::string>(argv + 1, argv + argc))) {
      const std::string& where = unknown->command;
      print_error(where.empty() ? "usage" : where,
                  fmt::format("{} (see 'markerctl {}{}--help')", markerctl::describe(*unknown), where,
                              where.empty() ? "" : " "));
      return markerctl::exit_usage;
    }
    const auto chosen = app.get_subcommands();
    const std::string where = chosen.empty() ? std::string("usage") : chosen.front()->get_name();
    const std::string help = chosen.empty() ? "markerctl --help" : fmt::format("markerctl {} --help", where);
    print_error(where, fmt::format("{} (see '{}')", e.what(), help));
    return markerctl::exit_usage;
  }
  for (const auto& command : commands) {
    if (command.app->parsed()) return run(command);
  }
  print_error("usage", "no command given (see 'markerctl --help')");
  return markerctl::exit_usage;
}
