// markerd.toml(5) against markerd's config parser: every key the parser
// accepts, in every table, is documented in the table's section of the page,
// and the page documents no key or table the parser does not read; and the
// page's examples are configs markerd takes.
//
// The keys come from the parser itself, not from a list kept here: each
// table of the shipped configs (config/*.toml) is given an unknown key,
// `zz_probe`, and the parser's refusal names the keys it knows there
// ("camera.sim.zz_probe: unknown key (known here: fps, exposure, ...)").
// A known key that names a table the document lacks is probed too, as
// `key = { zz_probe = 0 }`, so that tables no shipped config writes
// ([detector.frame8], [marker.frame]) are found as well. A key added to a
// parser's allow_only() list without a line in the page fails here.

#include <gtest/gtest.h>

#include <toml++/toml.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "markerd/base/config_table.hpp"
#include "markerd/daemon/daemon_config.hpp"
#include "markerd/rig/rig_config.hpp"
#include "support/files.hpp"

namespace markerd::daemon {
namespace {

namespace fs = std::filesystem;

const fs::path kSourceTree = MARKERD_SOURCE_DIR;
const fs::path kPage = kSourceTree / "docs/man/markerd.toml.5";
constexpr std::string_view kProbe = "zz_probe";

// Tables whose keys are names the user chooses (V4L2 and libcamera controls,
// Modbus buses): no list of known keys to compare with; their own tables,
// if any, are walked.
const std::set<std::string> kFreeFormTables = {"camera.v4l2.controls", "camera.libcamera.controls", "rig.buses"};

// A table path as the page's section names it: the two axes share their
// sections, as do the Modbus buses and the GPIO lines of an axis.
std::string section_name(const std::string& path) {
  static const std::vector<std::pair<std::regex, std::string>> kShared = {
      {std::regex(R"(^rig\.(rail|turntable)(\.|$))"), "rig.<axis>$2"},
      {std::regex(R"(^rig\.buses\.[^.]+)"), "rig.buses.<name>"},
      {std::regex(R"(^(rig\.<axis>\.gpio)\.[^.]+$)"), "$1.<line>"},
  };
  std::string name = path;
  for (const auto& [pattern, replacement] : kShared) name = std::regex_replace(name, pattern, replacement);
  return name;
}

std::string join(const std::vector<std::string>& path) {
  std::string out;
  for (const auto& key : path) out += (out.empty() ? "" : ".") + key;
  return out;
}

// One document: a shipped config, or one made from it for a camera source
// no shipped config uses. `source` is where it claims to be, so that its
// relative paths (the rig file, the camera model, register maps) resolve.
struct Document {
  std::string source;
  toml::table root;
};

// The keys the parser knows in table `path` of `doc`, from its refusal of
// zz_probe there; nullopt when it refuses something else first.
std::optional<std::vector<std::string>> known_keys(const Document& doc, const std::vector<std::string>& path,
                                                   std::string* message) {
  toml::table root = doc.root;
  toml::table* table = &root;
  for (const auto& key : path) {
    if (!table->contains(key)) table->insert(key, toml::table{});
    table = table->get(key)->as_table();
    if (table == nullptr) return std::nullopt;
  }
  table->insert_or_assign(kProbe, 0);
  try {
    (void)parse_daemon_config(ConfigTable(std::make_shared<const toml::table>(std::move(root)), doc.source));
    *message = "the config was accepted with the probe in it";
    return std::nullopt;
  } catch (const std::exception& e) {
    *message = e.what();
  }
  const std::string prefix = path.empty() ? std::string() : join(path) + ".";
  const std::regex refusal("(^|[ :])" + std::regex_replace(prefix, std::regex(R"(\.)"), R"(\.)") + std::string(kProbe) +
                           R"(: unknown key \(known here: ([^)]*)\))");
  std::smatch match;
  if (!std::regex_search(*message, match, refusal)) return std::nullopt;
  std::vector<std::string> keys;
  std::istringstream list(match[2].str());
  for (std::string key; std::getline(list, key, ',');) keys.push_back(key.substr(key.find_first_not_of(' ')));
  return keys;
}

// Every table the parser reads, by section name, with the keys it knows there.
struct ParserKeys {
  std::map<std::string, std::set<std::string>> tables;
  std::vector<std::string> failures;  // tables whose probe was not refused as unknown
};

void walk(const Document& doc, const std::vector<std::string>& path, ParserKeys& out) {
  const toml::node* node = path.empty() ? &doc.root : doc.root.at_path(join(path)).node();
  const toml::table* present = node != nullptr ? node->as_table() : nullptr;
  std::string message;
  const auto keys = known_keys(doc, path, &message);
  if (!keys) {
    if (kFreeFormTables.contains(join(path)) && present != nullptr) {
      for (const auto& [key, child] : *present) {
        if (child.is_table()) {
          auto next = path;
          next.emplace_back(key.str());
          walk(doc, next, out);
        }
      }
      return;
    }
    out.failures.push_back(doc.source + ": [" + join(path) + "]: " + message);
    return;
  }
  out.tables[section_name(join(path))].insert(keys->begin(), keys->end());
  for (const auto& key : *keys) {
    auto next = path;
    next.push_back(key);
    const toml::node* child = present != nullptr ? present->get(key) : nullptr;
    if (child != nullptr && child->is_table()) {
      walk(doc, next, out);
    } else if (child == nullptr) {
      // Absent here: a table the parser reads only if it is written?
      std::string ignored;
      if (known_keys(doc, next, &ignored)) walk(doc, next, out);
    }
  }
}

Document load(const fs::path& file) { return {file.string(), toml::parse_file(file.string())}; }

// config/markerd.toml with its V4L2 camera swapped for another source.
Document with_camera(const std::string& source, toml::table settings) {
  Document doc = load(kSourceTree / "config/markerd.toml");
  toml::table& camera = *doc.root["camera"].as_table();
  camera.erase("v4l2");
  camera.insert_or_assign("source", source);
  camera.insert_or_assign(source, std::move(settings));
  return doc;
}

const ParserKeys& parser_keys() {
  static const ParserKeys keys = [] {
    std::vector<Document> docs;
    for (const auto& entry : fs::directory_iterator(kSourceTree / "config")) {
      if (entry.is_regular_file() && entry.path().extension() == ".toml") docs.push_back(load(entry.path()));
    }
    // No shipped config reads a libcamera camera or a replayed file.
    docs.push_back(with_camera("libcamera", toml::table{{"width", 640}, {"height", 480}}));
    docs.push_back(with_camera("file", toml::table{{"path", "cameras"}}));
    ParserKeys out;
    for (const auto& doc : docs) walk(doc, {}, out);
    return out;
  }();
  return keys;
}

// The page's sections: a heading "[camera.sim]" is that table, "Top level"
// the root; the keys a section documents are the words of its .TP tag lines.
struct PageSections {
  std::map<std::string, std::set<std::string>> tables;
  std::vector<std::string> bad_tags;
};

std::string plain(std::string line) {
  line = std::regex_replace(line, std::regex(R"(^\.[A-Z]+ *)"), "");
  line = std::regex_replace(line, std::regex(R"(\\f[BIRP]|\\&|\\%|")"), "");
  return std::regex_replace(line, std::regex(R"(\\-)"), "-");
}

PageSections page_sections() {
  PageSections out;
  std::istringstream page(test_support::read_file(kPage));
  std::optional<std::string> table;
  bool tag = false;
  for (std::string line; std::getline(page, line);) {
    if (line.starts_with(".SH ") || line.starts_with(".SS ")) {
      const std::string title = plain(line);
      table.reset();
      if (line.starts_with(".SS ") && title == "Top level") table = "";
      if (line.starts_with(".SS ") && title.size() > 2 && title.front() == '[' && title.back() == ']') {
        table = title.substr(1, title.size() - 2);
      }
      if (table) out.tables[*table];
      continue;
    }
    if (!table) continue;
    if (line.starts_with(".TP")) {
      tag = true;
      continue;
    }
    if (!tag) continue;
    tag = false;
    std::istringstream words(std::regex_replace(plain(line), std::regex(","), " "));
    for (std::string word; words >> word;) {
      if (std::regex_match(word, std::regex("[a-z][a-z0-9_]*"))) {
        out.tables[*table].insert(word);
      } else {
        out.bad_tags.push_back("[" + *table + "]: " + line);
      }
    }
  }
  return out;
}

std::string joined(const std::set<std::string>& keys) {
  std::string out;
  for (const auto& key : keys) out += (out.empty() ? "" : ", ") + key;
  return out;
}

TEST(ManPageConfig, TheParserIsProbedInEveryTable) {
  const ParserKeys& keys = parser_keys();
  for (const auto& failure : keys.failures) ADD_FAILURE() << "no 'unknown key' refusal: " << failure;
  // What the walk must reach, or it has stopped working (the refusal's
  // wording changed, a shipped config went missing).
  for (const char* table : {"",
                            "marker",
                            "marker.frame",
                            "camera",
                            "camera.sim",
                            "camera.v4l2",
                            "camera.libcamera",
                            "camera.file",
                            "detector",
                            "detector.frame8",
                            "pipeline",
                            "log",
                            "control",
                            "sweep",
                            "rig",
                            "rig.geometry",
                            "rig.sim",
                            "rig.<axis>",
                            "rig.<axis>.homing",
                            "rig.<axis>.sim",
                            "rig.<axis>.gpio",
                            "rig.<axis>.gpio.<line>",
                            "rig.buses.<name>",
                            "rig.<axis>.modbus"}) {
    EXPECT_TRUE(keys.tables.contains(table)) << "the probe did not reach [" << table << "]";
  }
  EXPECT_GE(keys.tables.at("camera.sim").size(), 10U) << joined(keys.tables.at("camera.sim"));
}

TEST(ManPageConfig, EveryKeyTheParserReadsIsDocumented) {
  const ParserKeys& keys = parser_keys();
  const PageSections page = page_sections();
  for (const auto& [table, known] : keys.tables) {
    const std::string heading = table.empty() ? "Top level" : "[" + table + "]";
    const auto section = page.tables.find(table);
    if (section == page.tables.end()) {
      ADD_FAILURE() << "markerd.toml.5 has no section .SS \"" << heading << "\" for its keys: " << joined(known);
      continue;
    }
    for (const auto& key : known) {
      const std::string subtable = section_name(table.empty() ? key : table + "." + key);
      EXPECT_TRUE(section->second.contains(key) || page.tables.contains(subtable))
          << "markerd.toml.5: " << heading << " does not document " << key << " (a .TP item naming it, or a section ["
          << subtable << "])";
    }
  }
}

TEST(ManPageConfig, EveryDocumentedKeyIsRead) {
  const ParserKeys& keys = parser_keys();
  const PageSections page = page_sections();
  for (const auto& bad : page.bad_tags) ADD_FAILURE() << "a .TP item that is not a list of keys: " << bad;
  for (const auto& [table, documented] : page.tables) {
    const auto known = keys.tables.find(table);
    if (known == keys.tables.end()) {
      ADD_FAILURE() << "markerd.toml.5 documents [" << table << "], which markerd does not read";
      continue;
    }
    for (const auto& key : documented) {
      EXPECT_TRUE(known->second.contains(key))
          << "markerd.toml.5: [" << table << "] documents " << key << ", which markerd does not read there (it reads "
          << joined(known->second) << ")";
    }
  }
}

// The page's EXAMPLES, as a reader would copy them: the first a whole
// markerd.toml, the second a rig file.
std::vector<std::string> page_examples() {
  std::istringstream page(test_support::read_file(kPage));
  std::vector<std::string> examples;
  bool in_examples = false, in_block = false;
  for (std::string line; std::getline(page, line);) {
    if (line.starts_with(".SH ")) in_examples = line == ".SH EXAMPLES";
    if (!in_examples) continue;
    if (line == ".EX") {
      in_block = true;
      examples.emplace_back();
    } else if (line == ".EE") {
      in_block = false;
    } else if (in_block) {
      for (const auto& [escape, text] : std::vector<std::pair<std::string, std::string>>{
               {R"(\-)", "-"}, {R"(\(dq)", "\""}, {R"(\(aq)", "'"}, {R"(\e)", "\\"}}) {
        for (auto at = line.find(escape); at != std::string::npos; at = line.find(escape, at + text.size())) {
          line.replace(at, escape.size(), text);
        }
      }
      examples.back() += line + "\n";
    }
  }
  return examples;
}

TEST(ManPageConfig, ExamplesAreConfigsMarkerdTakes) {
  const auto examples = page_examples();
  ASSERT_EQ(examples.size(), 2U) << "markerd.toml.5's EXAMPLES: a markerd.toml, then a rig";
  // Beside the shipped examples, whose files (rig-gpio.toml, cameras/) it names.
  const std::string beside = (kSourceTree / "config/example.toml").string();
  try {
    const DaemonConfig config = parse_daemon_config(ConfigTable::parse(examples[0], beside));
    EXPECT_EQ(config.camera.source_kind, "v4l2");
    EXPECT_TRUE(config.rig.has_value());
  } catch (const std::exception& e) {
    ADD_FAILURE() << "the first example: " << e.what() << "\n" << examples[0];
  }
  try {
    (void)rig::parse_rig_config(ConfigTable::parse(examples[1], beside));
  } catch (const std::exception& e) {
    ADD_FAILURE() << "the second example: " << e.what() << "\n" << examples[1];
  }
}

}  // namespace
}  // namespace markerd::daemon
