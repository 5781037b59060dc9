// markerctl calibrate --rig RUN_DIR: reads a sweep run's records, fits the
// camera's intrinsics and the rig's geometry to its views of the marker,
// prints every parameter with its uncertainty and the reprojection error
// before and after, and writes the camera model (OpenCV's YAML) and the
// geometry's calibration file that a rig config names in [rig.geometry]
// calibration, so that later runs' ground truth uses them.

#include "cmd_calibrate_rig.hpp"

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "markerd/sweep/records.hpp"
#include "markerd/sweep/rig_calibration.hpp"

namespace markerctl {
namespace {

namespace fs = std::filesystem;
using markerd::sweep::RigCalibrationResult;
using markerd::sweep::RigParameter;
using markerd::sweep::RigParameterEstimate;

constexpr const char* kContext = "calibrate";

// --fix and --free take parameter names and these groups.
std::vector<RigParameter> named_parameters(const std::string& name, const char* option) {
  using markerd::sweep::is_intrinsic;
  std::vector<RigParameter> out;
  const auto all_where = [&](auto predicate) {
    for (std::size_t i = 0; i < markerd::sweep::kRigParameterCount; ++i) {
      const auto p = static_cast<RigParameter>(i);
      if (predicate(p)) out.push_back(p);
    }
  };
  if (name == "intrinsics") {
    all_where([](RigParameter p) { return is_intrinsic(p); });
  } else if (name == "distortion") {
    all_where([](RigParameter p) { return is_intrinsic(p) && markerd::sweep::parameter_unit(p).empty(); });
  } else if (name == "geometry") {
    all_where([](RigParameter p) { return !is_intrinsic(p); });
  } else if (const auto p = markerd::sweep::parameter_from_name(name)) {
    out.push_back(*p);
  } else {
    std::string names;
    for (std::size_t i = 0; i < markerd::sweep::kRigParameterCount; ++i) {
      names += fmt::format("{}, ", markerd::sweep::parameter_name(static_cast<RigParameter>(i)));
    }
    throw usage_error(kContext, fmt::format("{} {}: no such parameter (parameters: {}or the groups intrinsics, "
                                            "distortion, geometry)",
                                            option, name, names));
  }
  return out;
}

markerd::sweep::RigCalibrationOptions fit_options(const RigCalibrationArguments& a) {
  auto options = markerd::sweep::RigCalibrationOptions::defaults();
  for (const std::string& name : a.free) {
    for (const RigParameter p : named_parameters(name, "--free")) options.fixed[static_cast<std::size_t>(p)] = false;
  }
  for (const std::string& name : a.fix) {
    for (const RigParameter p : named_parameters(name, "--fix")) options.fixed[static_cast<std::size_t>(p)] = true;
  }
  return options;
}

markerd::sweep::RunRecords read_run(const std::string& directory) {
  std::error_code error;
  const auto status = fs::status(directory, error);
  if (!fs::exists(status)) throw runtime_error(kContext, fmt::format("--rig {}: no such run directory", directory));
  if (!fs::is_directory(status)) throw runtime_error(kContext, fmt::format("--rig {}: not a directory", directory));
  try {
    return markerd::sweep::read_run(directory);
  } catch (const std::exception& e) {
    throw runtime_error(kContext, fmt::format("--rig {}: {}", directory, e.what()));
  }
}

// "0.2104" for a standard deviation, the value to the same decimals.
int decimals_for(double sigma) {
  if (!(sigma > 0)) return 4;
  return std::clamp(2 - static_cast<int>(std::floor(std::log10(sigma))), 0, 9);
}

std::string format_value(double value, int decimals) { return fmt::format("{:.{}f}", value, decimals); }

std::string status_note(const RigParameterEstimate& e) {
  switch (e.status) {
    case RigParameterEstimate::Status::fitted: return "";
    case RigParameterEstimate::Status::fixed: return "fixed";
    case RigParameterEstimate::Status::not_observable: {
      std::string with;
      for (const RigParameter p : e.confounded_with) {
        with += fmt::format("{}{}", with.empty() ? "" : ", ", markerd::sweep::parameter_name(p));
      }
      return with.empty() ? "not observable: held" : fmt::format("not observable (only with {}): held", with);
    }
  }
  return "";
}

void print_text(const markerd::sweep::RigCalibrationRun& run, const RigCalibrationResult& fit,
                const std::string& directory) {
  std::string out = fmt::format(
      "run {}: {} measurements, {} views ({} corners of {} frames)\n"
      "RMS reprojection error: {:.3f} px before, {:.3f} px after (residual sigma {:.3f} px per coordinate; {} "
      "outlier corner{}; {} iterations{})\n\n",
      directory, run.measurements, fit.views, run.corners, run.frames, fit.rms_before_px, fit.rms_after_px,
      fit.residual_sigma_px, fit.outliers, fit.outliers == 1 ? "" : "s", fit.iterations,
      fit.converged ? "" : ", NOT converged");
  out += fmt::format("{:<26} {:>14} {:>14} {:>12}  {}\n", "parameter", "initial", "fitted", "+-1 sigma", "");
  for (const RigParameterEstimate& e : fit.parameters) {
    const int decimals = decimals_for(e.sigma);
    const std::string unit(markerd::sweep::parameter_unit(e.parameter));
    const std::string sigma =
        e.status == RigParameterEstimate::Status::fitted ? fmt::format("{:.2g}", e.sigma) : std::string();
    out += fmt::format("{:<26} {:>14} {:>14} {:>12}  {}\n", markerd::sweep::parameter_name(e.parameter),
                       format_value(e.initial, decimals), format_value(e.value, decimals), sigma,
                       e.status == RigParameterEstimate::Status::fitted ? unit : status_note(e));
  }
  if (!fit.strong_correlations.empty()) {
    out += "\nstrongly correlated (the views measure their combination better than each):\n";
    for (const auto& c : fit.strong_correlations) {
      out += fmt::format("  {} and {}: {:+.3f}\n", markerd::sweep::parameter_name(c.a),
                         markerd::sweep::parameter_name(c.b), c.rho);
    }
  }
  std::cout << out;
}

nlohmann::ordered_json to_json(const markerd::sweep::RigCalibrationRun& run, const RigCalibrationResult& fit,
                               const std::string& directory) {
  nlohmann::ordered_json parameters = nlohmann::ordered_json::array();
  for (const RigParameterEstimate& e : fit.parameters) {
    nlohmann::ordered_json with = nlohmann::ordered_json::array();
    for (const RigParameter p : e.confounded_with) with.push_back(std::string(markerd::sweep::parameter_name(p)));
    parameters.push_back({{"name", std::string(markerd::sweep::parameter_name(e.parameter))},
                          {"unit", std::string(markerd::sweep::parameter_unit(e.parameter))},
                          {"status", std::string(markerd::sweep::to_string(e.status))},
                          {"initial", e.initial},
                          {"value", e.value},
                          {"sigma", e.status == RigParameterEstimate::Status::fitted ? nlohmann::ordered_json(e.sigma)
                                                                                     : nlohmann::ordered_json(nullptr)},
                          {"confounded_with", with}});
  }
  nlohmann::ordered_json correlations = nlohmann::ordered_json::array();
  for (const auto& c : fit.strong_correlations) {
    correlations.push_back({{"a", std::string(markerd::sweep::parameter_name(c.a))},
                            {"b", std::string(markerd::sweep::parameter_name(c.b))},
                            {"rho", c.rho}});
  }
  return {{"run", directory},
          {"measurements", run.measurements},
          {"views", fit.views},
          {"frames", run.frames},
          {"corners", fit.corners},
          {"corners_of", run.corners},
          {"rms_before_px", fit.rms_before_px},
          {"rms_after_px", fit.rms_after_px},
          {"residual_sigma_px", fit.residual_sigma_px},
          {"huber_px", fit.huber_px},
          {"outliers", fit.outliers},
          {"iterations", fit.iterations},
          {"converged", fit.converged},
          {"parameters", parameters},
          {"correlations", correlations}};
}

}  // namespace

void add_rig_calibration_options(CLI::App& calibrate, RigCalibrationArguments& a) {
  calibrate
      .add_option("--rig", a.run,
                  "Fit the camera's intrinsics and the rig's geometry to a sweep run's views of the marker")
      ->type_name("RUN_DIR");
  calibrate
      .add_option("--rig-out", a.rig_out,
                  "With --rig: write the fitted geometry to this file, for [rig.geometry] calibration = \"FILE\"")
      ->type_name("FILE");
  calibrate
      .add_option("--fix", a.fix,
                  "With --rig: hold these at the run's values (names as printed, e.g. d0_mm or d0, cx; the groups "
                  "intrinsics, distortion, geometry)")
      ->type_name("NAME,...")
      ->delimiter(',');
  calibrate.add_option("--free", a.free, "With --rig: fit these too (p1, p2 and k3 are held unless freed); --fix wins")
      ->type_name("NAME,...")
      ->delimiter(',');
}

int run_rig_calibration(const RigCalibrationArguments& a, const std::string& camera_out, bool json) {
  if (a.run.empty()) throw usage_error(kContext, "--rig RUN_DIR: no run directory given");
  const markerd::sweep::RigCalibrationOptions options = fit_options(a);
  const markerd::sweep::RunRecords records = read_run(a.run);
  markerd::sweep::RigCalibrationRun run;
  try {
    run = markerd::sweep::rig_calibration_input(records);
  } catch (const std::exception& e) {
    throw runtime_error(kContext, fmt::format("--rig {}: {}", a.run, e.what()));
  }
  RigCalibrationResult fit;
  try {
    fit = markerd::sweep::calibrate_rig(run.input, options);
  } catch (const std::invalid_argument& e) {
    throw runtime_error(kContext, fmt::format("--rig {}: {}", a.run, e.what()));
  }
  if (!fit.converged) {
    throw runtime_error(kContext, fmt::format("--rig {}: the fit did not converge in {} iterations (RMS {:.3f} px); "
                                              "nothing written",
                                              a.run, fit.iterations, fit.rms_after_px));
  }

  nlohmann::ordered_json written = nlohmann::ordered_json::object();
  if (!camera_out.empty()) {
    fit.camera.save(camera_out);
    written["camera"] = camera_out;
  }
  if (!a.rig_out.empty()) {
    const std::string header = fmt::format(
        "The rig's geometry, fitted by markerctl calibrate --rig to run {} ({} views, RMS reprojection error {:.3f} "
        "px, was {:.3f} px).\nName this file in the rig config: [rig.geometry] calibration = \"{}\"; its keys "
        "override the table's.",
        records.start.run_id.empty() ? a.run : records.start.run_id, fit.views, fit.rms_after_px, fit.rms_before_px,
        fs::path(a.rig_out).filename().string());
    try {
      markerd::sweep::write_file_atomically(a.rig_out, markerd::sweep::rig_geometry_toml(fit, header));
    } catch (const std::exception& e) {
      throw runtime_error(kContext, fmt::format("--rig-out {}: {}", a.rig_out, e.what()));
    }
    written["rig"] = a.rig_out;
  }

  if (json) {
    nlohmann::ordered_json j = to_json(run, fit, a.run);
    j["written"] = written;
    std::cout << json_line(j) << "\n";
  } else {
    print_text(run, fit, a.run);
    if (written.contains("camera")) {
      std::cout << fmt::format("\nwrote {}: the camera model; name it in markerd's config, [camera] model\n",
                               camera_out);
    }
    if (written.contains("rig")) {
      std::cout << fmt::format(
          "wrote {}: the rig's geometry; name it in the rig config, [rig.geometry] "
          "calibration\n",
          a.rig_out);
    }
  }
  return 0;
}

}  // namespace markerctl
