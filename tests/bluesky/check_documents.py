#!/usr/bin/python3
"""Checks a run's documents.jsonl against Bluesky's event model.

Usage: check_documents.py SCHEMA_DIR DOCUMENTS_JSONL

Every line must be a [name, doc] pair whose doc the schema for its name
(SCHEMA_DIR/run_start.json, event_descriptor.json, event.json, run_stop.json:
docs/schemas/bluesky/) accepts, and the documents must hang together as one
run: one start, first; descriptors and a stop that name it; events whose
descriptor came before them, numbered from 1 without a gap in each stream,
whose data and timestamps have the descriptor's keys; a stop, last if any,
whose num_events counts them; no uid twice. Prints every problem, one a line,
and exits 1 if there was one; 2 when it cannot run (no jsonschema, unreadable
files). Run by tests/test_sweep_run.cpp with Debian's /usr/bin/python3 and
its python3-jsonschema.
"""

import json
import sys

try:
    import jsonschema
except ImportError:
    print("check_documents: cannot import jsonschema: install python3-jsonschema (tools/install-deps.sh)")
    sys.exit(2)

SCHEMAS = {"start": "run_start.json", "descriptor": "event_descriptor.json", "event": "event.json",
           "stop": "run_stop.json"}


def load_validators(schema_dir):
    validators = {}
    for name, file in SCHEMAS.items():
        with open(f"{schema_dir}/{file}", encoding="utf-8") as f:
            schema = json.load(f)
        cls = jsonschema.validators.validator_for(schema)
        cls.check_schema(schema)  # a schema that is not one would accept anything
        validators[name] = cls(schema)
    return validators


def check(validators, lines):
    problems = []
    documents = []
    for number, line in enumerate(lines, 1):
        try:
            pair = json.loads(line)
        except ValueError as e:
            problems.append(f"line {number}: not JSON: {e}")
            continue
        if not (isinstance(pair, list) and len(pair) == 2 and isinstance(pair[0], str)):
            problems.append(f"line {number}: not a [name, doc] pair")
            continue
        name, doc = pair
        if name not in validators:
            problems.append(f"line {number}: unknown document name {name!r}")
            continue
        for error in sorted(validators[name].iter_errors(doc), key=lambda e: list(e.absolute_path)):
            where = "/".join(str(p) for p in error.absolute_path) or "(the document)"
            problems.append(f"line {number}: {name} {where}: {error.message}")
        documents.append((number, name, doc))
    if problems:
        return problems  # the cross-references below assume the schemas' fields

    if not documents or documents[0][1] != "start":
        return problems + ["the first document is not a start"]
    start_uid = documents[0][2]["uid"]
    uids = {}
    descriptors = {}  # uid -> stream name
    seq_nums = {}  # descriptor uid -> the last seq_num seen
    counts = {}  # stream name -> events
    stops = 0
    for number, name, doc in documents:
        if doc["uid"] in uids:
            problems.append(f"line {number}: uid {doc['uid']} is line {uids[doc['uid']]}'s too")
        uids[doc["uid"]] = number
        if stops:
            problems.append(f"line {number}: a {name} after the stop")
        if name == "start" and number != documents[0][0]:
            problems.append(f"line {number}: a second start")
        elif name == "descriptor":
            if doc["run_start"] != start_uid:
                problems.append(f"line {number}: descriptor names run_start {doc['run_start']}, not {start_uid}")
            descriptors[doc["uid"]] = doc
            seq_nums[doc["uid"]] = 0
        elif name == "event":
            descriptor = descriptors.get(doc["descriptor"])
            if descriptor is None:
                problems.append(f"line {number}: event names descriptor {doc['descriptor']}, none before it")
                continue
            expected = seq_nums[doc["descriptor"]] + 1
            if doc["seq_num"] != expected:
                problems.append(f"line {number}: seq_num {doc['seq_num']}, expected {expected}")
            seq_nums[doc["descriptor"]] = doc["seq_num"]
            keys = set(descriptor["data_keys"])
            if set(doc["data"]) != keys:
                problems.append(f"line {number}: data keys {sorted(doc['data'])}, the descriptor's are {sorted(keys)}")
            if set(doc["timestamps"]) != set(doc["data"]):
                problems.append(f"line {number}: timestamps' keys are not data's")
            stream = descriptor.get("name", "primary")
            counts[stream] = counts.get(stream, 0) + 1
        elif name == "stop":
            stops += 1
            if doc["run_start"] != start_uid:
                problems.append(f"line {number}: stop names run_start {doc['run_start']}, not {start_uid}")
            num_events = doc.get("num_events", {})
            for stream in set(num_events) | set(counts):
                if num_events.get(stream, 0) != counts.get(stream, 0):
                    problems.append(f"line {number}: num_events says {num_events.get(stream, 0)} in {stream!r}, "
                                    f"the stream holds {counts.get(stream, 0)}")
    return problems


def main():
    if len(sys.argv) != 3:
        print(__doc__)
        return 2
    try:
        validators = load_validators(sys.argv[1])
        with open(sys.argv[2], encoding="utf-8") as f:
            lines = f.read().splitlines()
    except (OSError, ValueError, jsonschema.SchemaError) as e:
        print(f"check_documents: {e}")
        return 2
    problems = check(validators, lines)
    for p in problems:
        print(p)
    if problems:
        return 1
    print(f"check_documents: {len(lines)} documents, all valid")
    return 0


if __name__ == "__main__":
    sys.exit(main())
