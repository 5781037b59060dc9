#pragma once
// The records of one sweep run, in a directory of its own (docs/sweep.md):
//
//   start.json      the start document: plan, config, camera model, rig geometry,
//                   software version; written once, atomically, before anything moves
//   plan.toml       the plan's text as run
//   points.jsonl    one point document per measurement done, in run order
//   events.jsonl    what happened to the run: paused, resumed, suspended (and why),
//                   restarted after markerd stopped
//   stop.json       the stop document: exit status and reason; written once, atomically
//   documents.jsonl the run in Bluesky's event model, made from the others when
//                   the run ends (documents.hpp)
//
// start.json and stop.json are Bluesky's RunStart and RunStop documents
// (uid, time in UNIX seconds, exit_status success/abort/fail) with markerd's
// own fields beside Bluesky's. A point document is markerd's, with every
// frame in it; it carries the uid of the Event document it becomes in
// documents.jsonl, so that the documents made again are the same documents.
// points.jsonl doubles as the run's journal: a measurement is done when its
// line is on disk (each line is written whole, in one write() to a file
// opened O_APPEND, and synced before the run moves on), so a restart
// continues at the first measurement without a line, and nothing is
// recorded twice.

#include <array>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "markerd/base/unique_fd.hpp"
#include "markerd/sweep/plan.hpp"

namespace markerd::sweep {

// 2: start.json and stop.json are Bluesky's documents (uids, UNIX times,
// its exit statuses), points carry their event's uid. Records of schema 1
// (no uids, ISO times, exit status done/aborted/failed) are still read, so
// that runs recorded before still report and resume.
inline constexpr int kRunRecordSchema = 2;
inline constexpr int kOldestRunRecordSchema = 1;

// A marker's four corners in the image, pixels, in the marker frame's order
// (TL, TR, BR, BL: detector::Detection's).
using ImageCorners = std::array<std::array<double, 2>, 4>;

// One frame collected for a measurement, reduced to what the summaries need:
// whether the marker under test was found, and its pose and errors if so.
struct FrameSample {
  std::uint64_t sequence = 0;      // the camera's frame sequence number
  bool detected = false;           // the plan's marker (family and id) was found
  int other_markers = 0;           // detections of anything else (wrong ids, other families)
  bool has_pose = false;           // detected, with a pose (the camera model known)
  std::array<double, 3> tvec_m{};  // the marker in the camera frame
  std::array<double, 3> rvec{};    // Rodrigues vector, camera from marker
  double reprojection_error_px = 0;
  bool has_error = false;           // has_pose, and the ground truth known
  double translation_error_mm = 0;  // |t - t_truth|
  double distance_error_mm = 0;     // |t| - |t_truth|, signed
  double rotation_error_deg = 0;    // angle of R_truth^T R
  // Where the detector found the marker's corners: its outer square, and
  // frame8's hole (the square it measures, hole_fraction of the side). What
  // markerctl calibrate --rig fits the camera and the rig to. Absent when
  // the marker was not found, and in records written before markerd kept them.
  std::optional<ImageCorners> corners_px;
  std::optional<ImageCorners> inner_corners_px;
};

// The point document: one measurement (a repeat at a point).
struct PointRecord {
  std::string uid;       // its Event document's (empty in records of schema 1)
  std::size_t step = 0;  // PlanStep::index
  std::size_t grid = 0;
  std::size_t point = 0;
  int repeat = 0;
  double distance_m = 0;  // planned
  double angle_deg = 0;
  // Where the axes were while the frames were captured (the rig snapshot of
  // the first frame), and the marker pose those positions imply.
  double rail = 0;
  double turntable = 0;
  std::array<double, 3> truth_tvec_m{};
  double truth_distance_m = 0;
  double truth_yaw_deg = 0;
  int frames_corrupt = 0;  // frames the camera delivered broken, not counted in `frames`
  std::vector<FrameSample> frames;
  std::chrono::system_clock::time_point started{};   // the move began
  std::chrono::system_clock::time_point finished{};  // the last frame arrived
};

// The start document.
struct RunStart {
  std::string uid;     // the RunStart document's, uuid4 (empty in records of schema 1)
  std::string run_id;  // "20261201T061500Z-thesis"
  std::chrono::system_clock::time_point time{};
  std::string software_version;
  std::string hostname;
  SweepPlan plan;             // re-parsed from plan text when read
  std::size_t steps = 0;      // plan_steps(plan).size()
  nlohmann::json config;      // the daemon's config as it ran (file, text)
  nlohmann::json camera;      // the camera: source, model (intrinsics, distortion), frame rate
  nlohmann::json marker;      // the marker markerd's config describes: family, id, size, mounting, frame
  nlohmann::json rig;         // geometry, axes' units, units_per_step, limits, backends
  std::string detection_log;  // where the daemon's detection stream went when the run started
  // The uid of the descriptor of the run's stream of points (documents.hpp),
  // made with the run's own so that it stays one across resumes.
  std::string primary_descriptor_uid;

  // What the measured marker was mounted on: the plan's word, else (a plan
  // that does not say) markerd's config's, as `marker` keeps it; nothing for
  // records older than both. markerd refuses a plan that says otherwise
  // than its config, so the two never disagree.
  [[nodiscard]] std::optional<Mounting> marker_mounting() const;
};

// The event documents of events.jsonl.
struct RunEvent {
  std::chrono::system_clock::time_point time{};
  std::string kind;      // "started", "paused", "resumed", "suspended", "fault_cleared", "restarted"
  std::string reason;    // the cause, in words (empty when there is none)
  std::size_t step = 0;  // the step the run was at
};

// How a run ended, in markerd's words (the run states': what reports,
// logs and `sweep status` say).
enum class ExitStatus : std::uint8_t { done, aborted, failed };
[[nodiscard]] std::string_view to_string(ExitStatus status);
// The same in the stop document's words, Bluesky's: "success", "abort", "fail".
[[nodiscard]] std::string_view document_word(ExitStatus status);

// The stop document.
struct RunStop {
  std::chrono::system_clock::time_point time{};
  ExitStatus status = ExitStatus::done;
  std::string reason;
  std::size_t steps_done = 0;  // also its num_events: a point is an event
  std::string uid;             // the RunStop document's (empty in records of schema 1)
  std::string run_start;       // the start document's uid (empty when that has none)
};

// Everything read back from a run directory.
struct RunRecords {
  std::filesystem::path directory;
  RunStart start;
  std::vector<PointRecord> points;  // in file order
  std::vector<RunEvent> events;
  std::optional<RunStop> stop;  // absent while the run goes on (or was cut off)
  std::size_t torn_lines = 0;   // partial last lines ignored (a crash mid-write)
};

// Reads a run directory. std::runtime_error naming the file and line when a
// record cannot be read (a partial last line is not an error: it is counted).
RunRecords read_run(const std::filesystem::path& directory);

// JSON of each document (one line each; what the files hold).
nlohmann::json to_json(const PointRecord& record);
nlohmann::json to_json(const RunStart& start);
nlohmann::json to_json(const RunEvent& event);
nlohmann::json to_json(const RunStop& stop);
PointRecord point_from_json(const nlohmann::json& json);
RunEvent event_from_json(const nlohmann::json& json);
RunStop stop_from_json(const nlohmann::json& json);
RunStart start_from_json(const nlohmann::json& json);

// Writes a run's records as it goes. Not thread-safe: the runner's thread owns it.
class RunRecorder {
 public:
  // A new run: creates `directory` (its parent must exist), writes start.json
  // and plan.toml. std::runtime_error naming the path when it cannot.
  static RunRecorder create(const std::filesystem::path& directory, const RunStart& start);
  // An existing run, to continue: cuts a partial last line of points.jsonl
  // and events.jsonl (a crash mid-write) and opens both for appending.
  static RunRecorder resume(const std::filesystem::path& directory);

  // Appends the point's line and syncs it: when this returns the
  // measurement is done, whatever happens next.
  void append_point(const PointRecord& record);
  void append_event(const RunEvent& event);
  // Writes stop.json (atomically). Further appends are errors.
  void finish(const RunStop& stop);

  [[nodiscard]] const std::filesystem::path& directory() const { return directory_; }

  RunRecorder() = default;  // records nothing until assigned one made by create() or resume()

 private:
  std::filesystem::path directory_;
  UniqueFd points_fd_;
  UniqueFd events_fd_;
};

// Writes `text` to `path` so that a reader (or a crash) sees the old file or
// the new one, never a mixture: a temporary in the same directory, fsync,
// rename, fsync of the directory.
void write_file_atomically(const std::filesystem::path& path, std::string_view text);

// The fallback when write_file_atomically fails for want of space: writes
// `text` over the existing file's first bytes, padded with spaces to the
// file's old length (a JSON reader skips them), and syncs it. A small file's
// block is already allocated, so on a full disk this usually still works
// where a new temporary cannot be written. Not atomic: a crash in the middle
// can leave a mixture, which a reader must refuse (the journal's reader does:
// it fails to parse). std::runtime_error naming the path when it cannot.
void overwrite_file_in_place(const std::filesystem::path& path, std::string_view text);

}  // namespace markerd::sweep
