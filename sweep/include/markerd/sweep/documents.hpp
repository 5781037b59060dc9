#pragma once
// A run's records as Bluesky's event model has them (docs/sweep.md,
// "Bluesky's documents"): the start document, one descriptor for the stream
// of measurements ("primary"), one event per measurement, the stop document.
// Made from the records alone, whenever asked: start.json and stop.json are
// those documents already, and the records keep every uid (the start's, the
// descriptor's, each point's event's, the stop's), so the documents made
// again are the same documents. Per-frame detail stays in points.jsonl and
// the detection log: the events hold each measurement's reduction (the rig's
// ground truth, the detection rate, the mean pose and its errors).

#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "markerd/sweep/records.hpp"

namespace markerd::sweep {

inline constexpr const char* kPrimaryStream = "primary";
inline constexpr const char* kDocumentsFile = "documents.jsonl";

// One document and its name: "start", "descriptor", "event" or "stop".
struct Document {
  std::string name;
  nlohmann::json doc;
};

// The run's documents in order: start, descriptor, its events in run order,
// and the stop once the run has one. std::runtime_error naming what is
// missing when the records lack a uid: a run recorded before markerd gave
// runs uids (record schema 1) has no documents.
[[nodiscard]] std::vector<Document> run_documents(const RunRecords& records);

// The documents as JSON Lines of [name, doc] pairs, the form Bluesky's
// serializers (suitcase-jsonl) write.
[[nodiscard]] std::string documents_jsonl(const std::vector<Document>& documents);

// Writes the run's documents.jsonl in its directory, atomically.
void write_documents(const RunRecords& records);

}  // namespace markerd::sweep
