"""Record logs of studies (task farms): one JSON line per finished case, one file per rank.

A study of many independent cases (the anisotropy study) is checkpointed by its finished cases: each
rank appends the record of every case it finishes to ``DIR/records/rank-<r>.jsonl``, flushed and
synced at once, so a run killed at any moment keeps every finished case; a line cut by the kill is
ignored on reading. A restart reads the records of all ranks (on any number of ranks) and runs only
the cases that have none.
"""
import json
import os

RECORDS = "records"


class RecordLog:
    """Appends records (JSON-able dicts; NaN and inf allowed) to ``directory/records/rank-<rank>.jsonl``."""

    def __init__(self, directory, rank):
        folder = os.path.join(directory, RECORDS)
        os.makedirs(folder, exist_ok=True)
        self.path = os.path.join(folder, f"rank-{int(rank)}.jsonl")

    def append(self, record):
        line = json.dumps(record, sort_keys=True) + "\n"
        with open(self.path, "a") as fh:
            fh.write(line)
            fh.flush()
            os.fsync(fh.fileno())


def read_records(directory):
    """Every complete record under ``directory/records`` (all ranks' files), in file order; a
    truncated or corrupt line (a write cut by a kill) is skipped. ``[]`` when there is none."""
    folder = os.path.join(directory, RECORDS)
    if not os.path.isdir(folder):
        return []
    out = []
    for name in sorted(os.listdir(folder)):
        if not name.endswith(".jsonl"):
            continue
        with open(os.path.join(folder, name)) as fh:
            for line in fh:
                if not line.endswith("\n"):
                    continue          # the last line of a killed write
                try:
                    rec = json.loads(line)
                except json.JSONDecodeError:
                    continue
                if isinstance(rec, dict):
                    out.append(rec)
    return out


def write_study_header(directory, header):
    """``directory/study.json``: what a restart must match (the deck and the plan), atomically."""
    path = os.path.join(directory, "study.json")
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(header, fh, indent=1, sort_keys=True)
        fh.write("\n")
    os.replace(tmp, path)


def read_study_header(directory):
    """The header of a study directory, or None when it has none (not a study's output)."""
    path = os.path.join(directory, "study.json")
    if not os.path.isfile(path):
        return None
    with open(path) as fh:
        return json.load(fh)


def header_difference(old, new, parts):
    """The first difference between two study headers over their ``parts`` (e.g. "deck", "plan"):
    ``(part, key, value in old, value in new)``, or None when they agree (a restart may continue)."""
    for part in parts:
        if old.get(part) != new[part]:
            was = old.get(part) or {}
            keys = sorted(set(was) | set(new[part]))
            first = next((k for k in keys if was.get(k) != new[part].get(k)), part)
            return part, first, was.get(first), new[part].get(first)
    return None


def start_study_folder(directory, header, finished=None):
    """Rank 0: write the study header into ``directory`` and, on a restart, copy the records of the
    runs already done (``finished``: {id: record}) into ``records/rank-0.jsonl``, so that the new
    folder holds every record for a later restart."""
    write_study_header(directory, header)
    if finished:
        log = RecordLog(directory, 0)
        for rec in finished.values():
            log.append(rec)
