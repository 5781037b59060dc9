#include "markerd/sweep/records.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fmt/format.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <system_error>
#include <type_traits>
#include <utility>

#include "markerd/base/read_file.hpp"
#include "markerd/base/unique_fd.hpp"
#include "markerd/base/utc_time.hpp"

namespace markerd::sweep {

namespace fs = std::filesystem;

namespace {

constexpr const char* kStartFile = "start.json";
constexpr const char* kPlanFile = "plan.toml";
constexpr const char* kPointsFile = "points.jsonl";
constexpr const char* kEventsFile = "events.jsonl";
constexpr const char* kStopFile = "stop.json";

// A run directory may be handed in by a user (markerctl sweep report DIR):
// a FIFO or a device where a record should be must not hang the reader or
// fill memory. Hours of a sweep stay far below the limit.
constexpr std::size_t kMaxRecordFileBytes = std::size_t{256} << 20;

std::string read_record_file(const fs::path& path) {
  return read_regular_file(path, kMaxRecordFileBytes, "the run record");
}

[[noreturn]] void fail(const fs::path& path, std::string_view action, int error) {
  throw std::runtime_error(
      fmt::format("sweep records {}: cannot {}: {}", path.string(), action, std::generic_category().message(error)));
}

// UTC with milliseconds, "2026-12-01T06:15:00.123Z": sortable, and what
// every tool reads.
std::string to_iso(std::chrono::system_clock::time_point t) { return format_utc(t, UtcForm::milliseconds); }

// A field of a record, of the type markerd writes there; anything else is
// an error naming the field (the callers add the file and the line), never
// nlohmann's own message.
template <class T>
bool holds(const nlohmann::json& value) {
  if constexpr (std::is_same_v<T, std::string>) {
    return value.is_string();
  } else if constexpr (std::is_same_v<T, bool>) {
    return value.is_boolean();
  } else if constexpr (std::is_same_v<T, nlohmann::json>) {
    return value.is_object();
  } else {
    static_assert(std::is_integral_v<T>);
    if (value.is_number_unsigned()) return value.get<std::uint64_t>() <= std::uint64_t{std::numeric_limits<T>::max()};
    if constexpr (std::is_signed_v<T>) {
      return value.is_number_integer() && value.get<std::int64_t>() >= std::numeric_limits<T>::min();
    }
    return false;
  }
}

template <class T>
const char* wanted() {
  if constexpr (std::is_same_v<T, std::string>) return "a string";
  if constexpr (std::is_same_v<T, bool>) return "true or false";
  if constexpr (std::is_same_v<T, nlohmann::json>) return "a JSON object";
  if constexpr (std::is_unsigned_v<T>) return "a whole number from 0";
  return "a whole number";
}

const nlohmann::json* find_field(const nlohmann::json& json, const char* key) {
  if (!json.is_object()) throw std::runtime_error(fmt::format("not a JSON object where \"{}\" belongs", key));
  const auto it = json.find(key);
  return it == json.end() ? nullptr : &*it;
}

template <class T>
T checked(const nlohmann::json& value, const char* key) {
  if (!holds<T>(value))
    throw std::runtime_error(fmt::format("\"{}\" must be {}, got {}", key, wanted<T>(), value.dump()));
  return value.get<T>();
}

template <class T>
T field(const nlohmann::json& json, const char* key) {
  const nlohmann::json* value = find_field(json, key);
  if (value == nullptr) throw std::runtime_error(fmt::format("missing \"{}\"", key));
  return checked<T>(*value, key);
}

template <class T>
T optional_field(const nlohmann::json& json, const char* key, T fallback) {
  const nlohmann::json* value = find_field(json, key);
  return value == nullptr ? fallback : checked<T>(*value, key);
}

// Non-finite numbers are written as null (JSON has no NaN) and read back as NaN.
double number_or_nan(const nlohmann::json& value, const char* key) {
  if (value.is_null()) return std::numeric_limits<double>::quiet_NaN();
  if (!value.is_number()) throw std::runtime_error(fmt::format("\"{}\" must be a number, got {}", key, value.dump()));
  return value.get<double>();
}

double number(const nlohmann::json& json, const char* key) {
  const nlohmann::json* value = find_field(json, key);
  if (value == nullptr) throw std::runtime_error(fmt::format("missing \"{}\"", key));
  return number_or_nan(*value, key);
}

std::array<double, 3> vec3(const nlohmann::json& json, const char* key) {
  const nlohmann::json* a = find_field(json, key);
  if (a == nullptr || !a->is_array() || a->size() != 3) {
    throw std::runtime_error(fmt::format("\"{}\" is not three numbers", key));
  }
  std::array<double, 3> v{};
  for (std::size_t i = 0; i < 3; ++i) v[i] = number_or_nan((*a)[i], key);
  return v;
}

nlohmann::json json_vec3(const std::array<double, 3>& v) { return nlohmann::json::array({v[0], v[1], v[2]}); }

// Corners to a ten-thousandth of a pixel, far below what a detector
// resolves: a frame's line stays short.
nlohmann::json json_corners(const ImageCorners& corners) {
  nlohmann::json a = nlohmann::json::array();
  for (const auto& c : corners) a.push_back({std::round(c[0] * 1e4) / 1e4, std::round(c[1] * 1e4) / 1e4});
  return a;
}

std::optional<ImageCorners> corners(const nlohmann::json& json, const char* key) {
  const nlohmann::json* a = find_field(json, key);
  if (a == nullptr) return std::nullopt;
  ImageCorners c{};
  if (!a->is_array() || a->size() != 4) {
    throw std::runtime_error(fmt::format("\"{}\" is not four corners [x, y]", key));
  }
  for (std::size_t i = 0; i < 4; ++i) {
    const nlohmann::json& corner = (*a)[i];
    if (!corner.is_array() || corner.size() != 2 || !corner[0].is_number() || !corner[1].is_number()) {
      throw std::runtime_error(fmt::format("\"{}\" is not four corners [x, y]", key));
    }
    c[i] = {corner[0].get<double>(), corner[1].get<double>()};
  }
  return c;
}

void sync_directory(const fs::path& directory) {
  const UniqueFd fd(::open(directory.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC));
  if (!fd) fail(directory, "open the directory to sync it", errno);
  if (::fsync(fd.get()) != 0) fail(directory, "sync the directory", errno);
}

UniqueFd open_for_append(const fs::path& path) {
  UniqueFd fd(::open(path.c_str(), O_WRONLY | O_APPEND | O_CREAT | O_CLOEXEC, 0644));
  if (!fd) fail(path, "open for appending", errno);
  return fd;
}

// A file that does not end in '\n' ends in a line a crash cut short: it is
// cut off, so the next line starts a line of its own and the reader never
// sees half a record. Record files are small; reading them whole is fine.
void cut_partial_last_line(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return;
  const std::string content = read_record_file(path);
  if (content.empty() || content.back() == '\n') return;
  const std::size_t newline = content.rfind('\n');
  const off_t keep = newline == std::string::npos ? 0 : static_cast<off_t>(newline + 1);
  if (::truncate(path.c_str(), keep) != 0) fail(path, "cut off its partial last line", errno);
  const UniqueFd fd(::open(path.c_str(), O_WRONLY | O_CLOEXEC));
  if (!fd) fail(path, "open to sync", errno);
  if (::fsync(fd.get()) != 0) fail(path, "sync", errno);
}

// One line in one write() to a file opened O_APPEND, then synced. A write
// that fails part way is cut back, so the file keeps only whole lines.
void append_line(int fd, const fs::path& path, const std::string& line) {
  struct stat before {};
  if (::fstat(fd, &before) != 0) fail(path, "stat", errno);
  std::size_t written = 0;
  while (written < line.size()) {
    const ssize_t n = ::write(fd, line.data() + written, line.size() - written);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int error = n < 0 ? errno : EIO;
      if (written > 0) (void)::ftruncate(fd, before.st_size);
      fail(path, "append a record", error);
    }
    written += static_cast<std::size_t>(n);
  }
  if (::fdatasync(fd) != 0) fail(path, "sync", errno);
}

// Calls `take` for every whole line of a .jsonl file; returns the number of
// partial last lines skipped (0 or 1). A line that is whole but not a
// record is an error naming the file and the line.
template <class Take>
std::size_t read_lines(const fs::path& path, Take&& take) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return 0;
  const std::string content = read_record_file(path);
  std::size_t begin = 0;
  std::size_t line_number = 0;
  while (begin < content.size()) {
    const std::size_t end = content.find('\n', begin);
    if (end == std::string::npos) return 1;  // cut short by a crash: not a record
    ++line_number;
    try {
      take(nlohmann::json::parse(std::string_view(content).substr(begin, end - begin)));
    } catch (const std::exception& e) {
      throw std::runtime_error(fmt::format("{}:{}: not a record: {}", path.string(), line_number, e.what()));
    }
    begin = end + 1;
  }
  return 0;
}

// The record's schema, one this markerd reads.
int check_schema(const nlohmann::json& json) {
  const int schema = optional_field<int>(json, "schema", 0);
  if (schema < kOldestRunRecordSchema || schema > kRunRecordSchema) {
    throw std::runtime_error(fmt::format("record schema {} (this markerd reads {} to {})", schema,
                                         kOldestRunRecordSchema, kRunRecordSchema));
  }
  return schema;
}

// A start or stop document's time: UNIX seconds (Bluesky's), or in records
// of schema 1 the UTC text every other record keeps.
std::chrono::system_clock::time_point document_time(const nlohmann::json& json, int schema) {
  if (schema == 1) return parse_utc_milliseconds(field<std::string>(json, "time"));
  const nlohmann::json* value = find_field(json, "time");
  if (value == nullptr) throw std::runtime_error("missing \"time\"");
  if (!value->is_number()) {
    throw std::runtime_error(fmt::format("\"time\" must be seconds since 1970 (a number), got {}", value->dump()));
  }
  try {
    return from_unix_seconds(value->get<double>());
  } catch (const std::exception& e) {
    throw std::runtime_error(fmt::format("\"time\": {}", e.what()));
  }
}

}  // namespace

std::string_view to_string(ExitStatus status) {
  switch (status) {
    case ExitStatus::done: return "done";
    case ExitStatus::aborted: return "aborted";
    case ExitStatus::failed: return "failed";
  }
  return "?";
}

std::string_view document_word(ExitStatus status) {
  switch (status) {
    case ExitStatus::done: return "success";
    case ExitStatus::aborted: return "abort";
    case ExitStatus::failed: return "fail";
  }
  return "?";
}

nlohmann::json to_json(const PointRecord& r) {
  nlohmann::json frames = nlohmann::json::array();
  for (const FrameSample& f : r.frames) {
    nlohmann::json frame{{"seq", f.sequence}, {"detected", f.detected}, {"others", f.other_markers}};
    if (f.has_pose) {
      frame["tvec_m"] = json_vec3(f.tvec_m);
      frame["rvec"] = json_vec3(f.rvec);
      frame["reprojection_px"] = f.reprojection_error_px;
    }
    if (f.corners_px) frame["corners_px"] = json_corners(*f.corners_px);
    if (f.inner_corners_px) frame["inner_corners_px"] = json_corners(*f.inner_corners_px);
    if (f.has_error) {
      frame["error"] = {{"translation_mm", f.translation_error_mm},
                        {"distance_mm", f.distance_error_mm},
                        {"rotation_deg", f.rotation_error_deg}};
    }
    frames.push_back(std::move(frame));
  }
  return {{"schema", kRunRecordSchema},
          {"uid", r.uid},
          {"step", r.step},
          {"grid", r.grid},
          {"point", r.point},
          {"repeat", r.repeat},
          {"distance_m", r.distance_m},
          {"angle_deg", r.angle_deg},
          {"rail", r.rail},
          {"turntable", r.turntable},
          {"truth",
           {{"tvec_m", json_vec3(r.truth_tvec_m)}, {"distance_m", r.truth_distance_m}, {"yaw_deg", r.truth_yaw_deg}}},
          {"frames_corrupt", r.frames_corrupt},
          {"started", to_iso(r.started)},
          {"finished", to_iso(r.finished)},
          {"frames", std::move(frames)}};
}

PointRecord point_from_json(const nlohmann::json& j) {
  check_schema(j);
  PointRecord r;
  r.uid = optional_field<std::string>(j, "uid", "");
  r.step = field<std::size_t>(j, "step");
  r.grid = field<std::size_t>(j, "grid");
  r.point = field<std::size_t>(j, "point");
  r.repeat = field<int>(j, "repeat");
  r.distance_m = number(j, "distance_m");
  r.angle_deg = number(j, "angle_deg");
  r.rail = number(j, "rail");
  r.turntable = number(j, "turntable");
  const auto truth = field<nlohmann::json>(j, "truth");
  r.truth_tvec_m = vec3(truth, "tvec_m");
  r.truth_distance_m = number(truth, "distance_m");
  r.truth_yaw_deg = number(truth, "yaw_deg");
  r.frames_corrupt = field<int>(j, "frames_corrupt");
  r.started = parse_utc_milliseconds(field<std::string>(j, "started"));
  r.finished = parse_utc_milliseconds(field<std::string>(j, "finished"));
  const nlohmann::json* frames = find_field(j, "frames");
  if (frames == nullptr || !frames->is_array()) throw std::runtime_error("\"frames\" must be an array");
  for (const auto& f : *frames) {
    FrameSample s;
    s.sequence = field<std::uint64_t>(f, "seq");
    s.detected = field<bool>(f, "detected");
    s.other_markers = field<int>(f, "others");
    if (f.contains("tvec_m")) {
      s.has_pose = true;
      s.tvec_m = vec3(f, "tvec_m");
      s.rvec = vec3(f, "rvec");
      s.reprojection_error_px = number(f, "reprojection_px");
    }
    s.corners_px = corners(f, "corners_px");
    s.inner_corners_px = corners(f, "inner_corners_px");
    if (const auto e = f.find("error"); e != f.end()) {
      s.has_error = true;
      s.translation_error_mm = number(*e, "translation_mm");
      s.distance_error_mm = number(*e, "distance_mm");
      s.rotation_error_deg = number(*e, "rotation_deg");
    }
    r.frames.push_back(s);
  }
  return r;
}

std::optional<Mounting> RunStart::marker_mounting() const {
  if (plan.marker.mounting) return plan.marker.mounting;
  const auto at = marker.find("mounting");
  if (!marker.is_object() || at == marker.end() || !at->is_string()) return std::nullopt;
  return mounting_from_name(at->get<std::string>());
}

nlohmann::json to_json(const RunStart& s) {
  return {{"schema", kRunRecordSchema},
          {"uid", s.uid},
          {"run_id", s.run_id},
          {"time", unix_seconds(s.time)},
          {"software_version", s.software_version},
          {"hostname", s.hostname},
          {"plan", {{"source", s.plan.source}, {"name", s.plan.name}, {"text", s.plan.text}}},
          {"steps", s.steps},
          {"config", s.config},
          {"camera", s.camera},
          {"marker", s.marker},
          {"rig", s.rig},
          {"detection_log", s.detection_log},
          {"descriptors", {{"primary", s.primary_descriptor_uid}}}};
}

RunStart start_from_json(const nlohmann::json& j) {
  const int schema = check_schema(j);
  RunStart s;
  s.uid = optional_field<std::string>(j, "uid", "");
  s.run_id = field<std::string>(j, "run_id");
  s.time = document_time(j, schema);
  s.software_version = optional_field<std::string>(j, "software_version", "");
  s.hostname = optional_field<std::string>(j, "hostname", "");
  const auto plan = field<nlohmann::json>(j, "plan");
  // The plan as it ran, from its own text: the record holds what was read,
  // not this markerd's idea of it.
  s.plan = parse_plan(field<std::string>(plan, "text"), optional_field<std::string>(plan, "source", "<run record>"));
  s.steps = field<std::size_t>(j, "steps");
  s.config = j.value("config", nlohmann::json::object());
  s.camera = j.value("camera", nlohmann::json::object());
  s.marker = j.value("marker", nlohmann::json::object());  // older records: not kept
  s.rig = j.value("rig", nlohmann::json::object());
  s.detection_log = optional_field<std::string>(j, "detection_log", "");
  const auto descriptors = optional_field<nlohmann::json>(j, "descriptors", nlohmann::json::object());
  s.primary_descriptor_uid = optional_field<std::string>(descriptors, "primary", "");
  return s;
}

nlohmann::json to_json(const RunEvent& e) {
  return {{"schema", kRunRecordSchema},
          {"time", to_iso(e.time)},
          {"event", e.kind},
          {"reason", e.reason},
          {"step", e.step}};
}

RunEvent event_from_json(const nlohmann::json& j) {
  check_schema(j);
  RunEvent e;
  e.time = parse_utc_milliseconds(field<std::string>(j, "time"));
  e.kind = field<std::string>(j, "event");
  e.reason = optional_field<std::string>(j, "reason", "");
  e.step = optional_field<std::size_t>(j, "step", 0);
  return e;
}

nlohmann::json to_json(const RunStop& s) {
  nlohmann::json j{{"schema", kRunRecordSchema},   {"uid", s.uid},
                   {"time", unix_seconds(s.time)}, {"exit_status", document_word(s.status)},
                   {"reason", s.reason},           {"num_events", {{"primary", s.steps_done}}},
                   {"steps_done", s.steps_done}};
  // A run recorded before runs had uids has no start uid to name: better no
  // reference than an empty one.
  if (!s.run_start.empty()) j["run_start"] = s.run_start;
  return j;
}

RunStop stop_from_json(const nlohmann::json& j) {
  const int schema = check_schema(j);
  RunStop s;
  s.uid = optional_field<std::string>(j, "uid", "");
  s.run_start = optional_field<std::string>(j, "run_start", "");
  s.time = document_time(j, schema);
  const std::string status = field<std::string>(j, "exit_status");
  // Bluesky's words; markerd's own in stop records of schema 1.
  if (status == "success" || status == "done")
    s.status = ExitStatus::done;
  else if (status == "abort" || status == "aborted")
    s.status = ExitStatus::aborted;
  else if (status == "fail" || status == "failed")
    s.status = ExitStatus::failed;
  else
    throw std::runtime_error(fmt::format("unknown exit_status \"{}\" (success, abort or fail)", status));
  s.reason = optional_field<std::string>(j, "reason", "");
  s.steps_done = optional_field<std::size_t>(j, "steps_done", 0);
  return s;
}

RunRecords read_run(const fs::path& directory) {
  RunRecords records;
  records.directory = directory;
  const fs::path start_path = directory / kStartFile;
  std::error_code ec;
  if (!fs::is_directory(directory, ec)) {
    throw std::runtime_error(fmt::format("sweep run {}: not a directory", directory.string()));
  }
  if (!fs::exists(start_path, ec)) {
    throw std::runtime_error(fmt::format("sweep run {}: no {} (not a run directory?)", directory.string(), kStartFile));
  }
  try {
    records.start = start_from_json(nlohmann::json::parse(read_record_file(start_path)));
  } catch (const FileError&) {
    throw;  // names the file already
  } catch (const std::exception& e) {
    throw std::runtime_error(fmt::format("{}: {}", start_path.string(), e.what()));
  }
  records.torn_lines += read_lines(directory / kPointsFile,
                                   [&](const nlohmann::json& j) { records.points.push_back(point_from_json(j)); });
  records.torn_lines += read_lines(directory / kEventsFile,
                                   [&](const nlohmann::json& j) { records.events.push_back(event_from_json(j)); });
  const fs::path stop_path = directory / kStopFile;
  if (fs::exists(stop_path, ec)) {
    try {
      records.stop = stop_from_json(nlohmann::json::parse(read_record_file(stop_path)));
    } catch (const FileError&) {
      throw;  // names the file already
    } catch (const std::exception& e) {
      throw std::runtime_error(fmt::format("{}: {}", stop_path.string(), e.what()));
    }
  }
  return records;
}

void write_file_atomically(const fs::path& path, std::string_view text) {
  const fs::path temporary = fs::path(path).concat(".tmp");
  UniqueFd fd(::open(temporary.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644));
  if (!fd) fail(temporary, "create", errno);
  std::size_t written = 0;
  while (written < text.size()) {
    const ssize_t n = ::write(fd.get(), text.data() + written, text.size() - written);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) fail(temporary, "write", n < 0 ? errno : EIO);
    written += static_cast<std::size_t>(n);
  }
  if (::fsync(fd.get()) != 0) fail(temporary, "sync", errno);
  if (fd.close() != 0) fail(temporary, "close", errno);
  if (::rename(temporary.c_str(), path.c_str()) != 0) fail(path, "rename into place", errno);
  sync_directory(path.has_parent_path() ? path.parent_path() : fs::path("."));
}

void overwrite_file_in_place(const fs::path& path, std::string_view text) {
  const UniqueFd fd(::open(path.c_str(), O_WRONLY | O_CLOEXEC));
  if (!fd) fail(path, "open to overwrite", errno);
  struct stat st {};
  if (::fstat(fd.get(), &st) != 0) fail(path, "stat", errno);
  std::string padded(text);
  if (std::cmp_less(padded.size(), st.st_size)) padded.resize(static_cast<std::size_t>(st.st_size), ' ');
  std::size_t written = 0;
  while (written < padded.size()) {
    const ssize_t n = ::pwrite(fd.get(), padded.data() + written, padded.size() - written, static_cast<off_t>(written));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) fail(path, "overwrite", n < 0 ? errno : EIO);
    written += static_cast<std::size_t>(n);
  }
  if (::fdatasync(fd.get()) != 0) fail(path, "sync", errno);
}

RunRecorder RunRecorder::create(const fs::path& directory, const RunStart& start) {
  if (::mkdir(directory.c_str(), 0755) != 0) fail(directory, "create the run directory", errno);
  sync_directory(directory.has_parent_path() ? directory.parent_path() : fs::path("."));
  write_file_atomically(directory / kPlanFile, start.plan.text);
  // start.json last: a directory with it is a run, whatever else is there.
  write_file_atomically(directory / kStartFile, to_json(start).dump(2) + "\n");
  return resume(directory);
}

RunRecorder RunRecorder::resume(const fs::path& directory) {
  RunRecorder recorder;
  recorder.directory_ = directory;
  cut_partial_last_line(directory / kPointsFile);
  cut_partial_last_line(directory / kEventsFile);
  recorder.points_fd_ = open_for_append(directory / kPointsFile);
  recorder.events_fd_ = open_for_append(directory / kEventsFile);
  sync_directory(directory);  // the two files' names are on disk
  return recorder;
}

void RunRecorder::append_point(const PointRecord& record) {
  if (!points_fd_) throw std::logic_error("sweep records: the run is finished");
  append_line(points_fd_.get(), directory_ / kPointsFile, to_json(record).dump() + "\n");
}

void RunRecorder::append_event(const RunEvent& event) {
  if (!events_fd_) throw std::logic_error("sweep records: the run is finished");
  append_line(events_fd_.get(), directory_ / kEventsFile, to_json(event).dump() + "\n");
}

void RunRecorder::finish(const RunStop& stop) {
  write_file_atomically(directory_ / kStopFile, to_json(stop).dump(2) + "\n");
  points_fd_.reset();
  events_fd_.reset();
}

}  // namespace markerd::sweep
