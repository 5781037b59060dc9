#pragma once
// markerctl calibrate --live N: a camera calibration's views taken from a
// running markerd's frames (the control socket's `snapshot`) while a person
// moves the board before the camera; a frame becomes a view when the board
// in it is still and stands apart from the views kept so far
// (detector/view_picker.hpp).

#include <string>
#include <vector>

#include "markerd/detector/board.hpp"
#include "markerd/detector/calibration.hpp"

namespace markerctl {

struct LiveCalibrationOptions {
  int views = 0;         // how many to keep
  std::string socket;    // markerd's control socket (control_socket_path's rules)
  std::string keep_dir;  // where the kept frames go as PNG; none when empty
};

struct LiveViews {
  std::vector<markerd::detector::CalibrationView> views;
  int width = 0;
  int height = 0;
  bool interrupted = false;  // a signal ended the gathering before `views` were kept
};

// Takes markerd's frames until `options.views` are kept or an interrupt
// (SIGINT, SIGTERM, SIGHUP, SIGQUIT) ends it, telling the person on a live
// line on stderr what each frame lacks. A kept view is named by its file
// under keep_dir, else by markerd's frame number. Throws CommandError when
// markerd cannot be reached, stops sending frames, or changes the frame size.
LiveViews gather_live_views(const LiveCalibrationOptions& options, markerd::detector::BoardDetector& detector,
                            int min_points);

}  // namespace markerctl
