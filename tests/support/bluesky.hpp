#pragma once
// A run's documents.jsonl checked against Bluesky's event model by
// tests/bluesky/check_documents.py, with Debian's python3 and its
// python3-jsonschema (tools/install-deps.sh), against the schemas in
// docs/schemas/bluesky/. Exit 0: valid; 1: the problems, one a line; 2: the
// checker could not run.

#include <filesystem>

#include "process.hpp"
#include "toml_config.hpp"

namespace markerd::test_support {

inline Outcome check_bluesky_documents(const std::filesystem::path& documents) {
  return run_program({"/usr/bin/python3", (kSourceTree / "tests/bluesky/check_documents.py").string(),
                      (kSourceTree / "docs/schemas/bluesky").string(), documents.string()});
}

}  // namespace markerd::test_support
