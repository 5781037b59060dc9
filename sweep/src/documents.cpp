#include "markerd/sweep/documents.hpp"

#include <fmt/format.h>

#include <array>
#include <cmath>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string_view>
#include <utility>

#include "markerd/base/utc_time.hpp"

namespace markerd::sweep {

namespace {

// Where an event's data come from, as the descriptor's object_keys group
// them: what the plan asked, where the rig stood, what the detector found.
constexpr const char* kPlanSource = "markerd:plan";
constexpr const char* kRigSource = "markerd:rig";
constexpr const char* kDetectorSource = "markerd:detector";

struct DataKey {
  const char* name;
  const char* source;
  const char* dtype;  // Bluesky's: "number", "integer", "array"
  int length;         // of an array; 0: a scalar
  std::optional<std::string> units;
};

// An axis's unit as the start record keeps it ("mm", "deg"), if it does.
std::optional<std::string> axis_unit(const RunStart& start, const char* axis) {
  const auto at = start.rig.find(axis);
  if (!start.rig.is_object() || at == start.rig.end() || !at->is_object()) return std::nullopt;
  const auto unit = at->find("unit");
  if (unit == at->end() || !unit->is_string()) return std::nullopt;
  return unit->get<std::string>();
}

// The keys of the primary stream's events. An event's values follow this
// order (event_data); a key added here needs its value there.
std::vector<DataKey> primary_data_keys(const RunStart& start) {
  return {
      {"step", kPlanSource, "integer", 0, std::nullopt},
      {"grid", kPlanSource, "integer", 0, std::nullopt},
      {"point", kPlanSource, "integer", 0, std::nullopt},
      {"repeat", kPlanSource, "integer", 0, std::nullopt},
      {"distance_m", kPlanSource, "number", 0, "m"},
      {"angle_deg", kPlanSource, "number", 0, "deg"},
      {"rail", kRigSource, "number", 0, axis_unit(start, "rail")},
      {"turntable", kRigSource, "number", 0, axis_unit(start, "turntable")},
      {"truth_distance_m", kRigSource, "number", 0, "m"},
      {"truth_yaw_deg", kRigSource, "number", 0, "deg"},
      {"truth_tvec_m", kRigSource, "array", 3, "m"},
      {"frames", kDetectorSource, "integer", 0, std::nullopt},
      {"frames_detected", kDetectorSource, "integer", 0, std::nullopt},
      {"frames_corrupt", kDetectorSource, "integer", 0, std::nullopt},
      {"other_markers", kDetectorSource, "integer", 0, std::nullopt},
      {"detection_rate", kDetectorSource, "number", 0, std::nullopt},
      {"tvec_m", kDetectorSource, "array", 3, "m"},
      {"translation_error_mm", kDetectorSource, "number", 0, "mm"},
      {"distance_error_mm", kDetectorSource, "number", 0, "mm"},
      {"rotation_error_deg", kDetectorSource, "number", 0, "deg"},
      {"reprojection_error_px", kDetectorSource, "number", 0, "px"},
  };
}

nlohmann::json descriptor_document(const RunStart& start) {
  nlohmann::json data_keys = nlohmann::json::object();
  nlohmann::json object_keys = {
      {"plan", nlohmann::json::array()}, {"rig", nlohmann::json::array()}, {"detector", nlohmann::json::array()}};
  for (const DataKey& key : primary_data_keys(start)) {
    nlohmann::json entry{{"source", key.source},
                         {"dtype", key.dtype},
                         {"shape", key.length > 0 ? nlohmann::json::array({key.length}) : nlohmann::json::array()}};
    if (key.units) entry["units"] = *key.units;
    data_keys[key.name] = std::move(entry);
    const std::string_view source(key.source);
    object_keys[std::string(source.substr(source.find(':') + 1))].push_back(key.name);
  }
  return {{"uid", start.primary_descriptor_uid}, {"run_start", start.uid},
          {"time", unix_seconds(start.time)},    {"name", kPrimaryStream},
          {"data_keys", std::move(data_keys)},   {"object_keys", std::move(object_keys)}};
}

// Mean of what was seen; NaN, written as null, when nothing was.
struct Mean {
  double sum = 0;
  int n = 0;
  void add(double value) {
    sum += value;
    ++n;
  }
  [[nodiscard]] double value() const { return n > 0 ? sum / n : std::numeric_limits<double>::quiet_NaN(); }
};

nlohmann::json number_or_null(double value) { return std::isfinite(value) ? nlohmann::json(value) : nlohmann::json(); }

nlohmann::json vec3_or_null(const std::array<Mean, 3>& v) {
  return nlohmann::json::array(
      {number_or_null(v[0].value()), number_or_null(v[1].value()), number_or_null(v[2].value())});
}

// One measurement's reduction: its frames, those with the plan's marker,
// and the mean pose and errors over the frames that have them.
nlohmann::json event_data(const PointRecord& r) {
  int detected = 0;
  int others = 0;
  std::array<Mean, 3> tvec;
  Mean translation_error;
  Mean distance_error;
  Mean rotation_error;
  Mean reprojection_error;
  for (const FrameSample& f : r.frames) {
    detected += f.detected ? 1 : 0;
    others += f.other_markers;
    if (f.has_pose) {
      for (std::size_t i = 0; i < 3; ++i) tvec[i].add(f.tvec_m[i]);
      reprojection_error.add(f.reprojection_error_px);
    }
    if (f.has_error) {
      translation_error.add(f.translation_error_mm);
      distance_error.add(f.distance_error_mm);
      rotation_error.add(f.rotation_error_deg);
    }
  }
  const int frames = static_cast<int>(r.frames.size());
  return {{"step", r.step},
          {"grid", r.grid},
          {"point", r.point},
          {"repeat", r.repeat},
          {"distance_m", number_or_null(r.distance_m)},
          {"angle_deg", number_or_null(r.angle_deg)},
          {"rail", number_or_null(r.rail)},
          {"turntable", number_or_null(r.turntable)},
          {"truth_distance_m", number_or_null(r.truth_distance_m)},
          {"truth_yaw_deg", number_or_null(r.truth_yaw_deg)},
          {"truth_tvec_m", nlohmann::json::array({number_or_null(r.truth_tvec_m[0]), number_or_null(r.truth_tvec_m[1]),
                                                  number_or_null(r.truth_tvec_m[2])})},
          {"frames", frames},
          {"frames_detected", detected},
          {"frames_corrupt", r.frames_corrupt},
          {"other_markers", others},
          {"detection_rate", frames > 0 ? static_cast<double>(detected) / frames : 0.0},
          {"tvec_m", vec3_or_null(tvec)},
          {"translation_error_mm", number_or_null(translation_error.value())},
          {"distance_error_mm", number_or_null(distance_error.value())},
          {"rotation_error_deg", number_or_null(rotation_error.value())},
          {"reprojection_error_px", number_or_null(reprojection_error.value())}};
}

// The event of a measurement: its time is when its last frame arrived, and
// so is every value's (the rig's position is the first frame's snapshot,
// taken while the axes stood still at the point).
nlohmann::json event_document(const PointRecord& r, std::size_t seq_num, const std::string& descriptor_uid) {
  const double time = unix_seconds(r.finished);
  nlohmann::json data = event_data(r);
  nlohmann::json timestamps = nlohmann::json::object();
  for (const auto& [key, value] : data.items()) timestamps[key] = time;
  return {{"uid", r.uid},       {"descriptor", descriptor_uid}, {"time", time},
          {"seq_num", seq_num}, {"data", std::move(data)},      {"timestamps", std::move(timestamps)}};
}

void require_uid(const std::string& uid, const std::string& what, const RunRecords& records) {
  if (!uid.empty()) return;
  throw std::runtime_error(fmt::format(
      "sweep run {}: {} has no uid (a run recorded before markerd gave its documents uids has no Bluesky documents)",
      records.directory.string(), what));
}

}  // namespace

std::vector<Document> run_documents(const RunRecords& records) {
  const RunStart& start = records.start;
  require_uid(start.uid, "start.json", records);
  require_uid(start.primary_descriptor_uid, "start.json's primary descriptor", records);
  std::vector<Document> documents;
  documents.reserve(records.points.size() + 3);
  documents.push_back({"start", to_json(start)});
  documents.push_back({"descriptor", descriptor_document(start)});
  for (std::size_t i = 0; i < records.points.size(); ++i) {
    require_uid(records.points[i].uid, fmt::format("points.jsonl line {}", i + 1), records);
    documents.push_back({"event", event_document(records.points[i], i + 1, start.primary_descriptor_uid)});
  }
  if (records.stop) {
    const RunStop& stop = *records.stop;
    require_uid(stop.uid, "stop.json", records);
    // Bluesky's readers trust both: a stop that names another run, or counts
    // other events than the stream holds, would mislead them.
    if (stop.run_start != start.uid) {
      throw std::runtime_error(fmt::format("sweep run {}: stop.json names run_start \"{}\", start.json's uid is \"{}\"",
                                           records.directory.string(), stop.run_start, start.uid));
    }
    if (stop.steps_done != records.points.size()) {
      throw std::runtime_error(fmt::format("sweep run {}: stop.json counts {} steps done, points.jsonl holds {}",
                                           records.directory.string(), stop.steps_done, records.points.size()));
    }
    documents.push_back({"stop", to_json(stop)});
  }
  return documents;
}

std::string documents_jsonl(const std::vector<Document>& documents) {
  std::string text;
  for (const Document& d : documents) {
    text += nlohmann::json::array({d.name, d.doc}).dump();
    text += '\n';
  }
  return text;
}

void write_documents(const RunRecords& records) {
  write_file_atomically(records.directory / kDocumentsFile, documents_jsonl(run_documents(records)));
}

}  // namespace markerd::sweep
