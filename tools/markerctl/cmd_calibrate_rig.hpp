#pragma once
// markerctl calibrate --rig RUN_DIR: the camera's intrinsics and the rig's
// geometry fitted to a sweep run's views of the marker
// (sweep/rig_calibration.hpp, docs/calibration-rig.md). Kept apart from the
// image-based calibration (cmd_calibrate.cpp), which adds these options to
// its subcommand and hands the run over when --rig is given; -o (the camera
// file) and --json are the subcommand's.

#include <string>
#include <vector>

#include "common.hpp"

namespace markerctl {

struct RigCalibrationArguments {
  std::string run;      // --rig: the run directory; empty: not a rig calibration
  std::string rig_out;  // --rig-out: the rig geometry's calibration file
  std::vector<std::string> fix;
  std::vector<std::string> free;
};

// Adds --rig, --rig-out, --fix and --free to `calibrate`.
void add_rig_calibration_options(CLI::App& calibrate, RigCalibrationArguments& arguments);
// Fits and reports; writes the camera model to `camera_out` and the geometry
// to arguments.rig_out where given. The exit status.
int run_rig_calibration(const RigCalibrationArguments& arguments, const std::string& camera_out, bool json);

}  // namespace markerctl
