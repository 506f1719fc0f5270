"""A run folder as the report reads it: ``Run`` (its finished episodes, summary, config and the
CPU code paths it ran on), ``load_run`` with the warnings about what in the folder is damaged or
disagrees, and the checks of ``--names``. Its own module because everything else in the report
(tables, paired statistics, time budgets, plots) works on loaded runs, and ``tools diff`` loads
runs the same way without the rest of the report.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tools.cli import check_text_path


PHASES = ("FindObj", "Pick", "FindRec", "Place", "SR")


@dataclass
class Run:
    name: str
    path: Path
    records: list[dict]
    summary: dict
    config: dict
    legacy: int = 0             # records without a configuration fingerprint (written before they existed)
    cpu: tuple[str, ...] = ()   # the CPU code paths its invocations ran on (tasks.run_folder.run_cpu_paths)
    cpu_models: tuple[str, ...] = ()   # the CPUs they ran on, where recorded (tasks.run_folder.run_cpu_models)


MAX_LISTED_DAMAGE = 10     # damaged lines named one by one (FILE:LINE) per run folder; the rest are counted
MAX_NAME_CHARS = 100       # a --names name (row labels, file and folder names of the episode pages)


def check_names(names: list[str]) -> None:
    """CliError for a --names name that is empty, too long, holds control characters or is given
    twice (names are row labels and become folder names of the episode pages)."""
    from helios.schema import short_repr
    from tools.cli import CliError

    for n in names:
        if not n:
            raise CliError("--names has an empty name")
        if len(n) > MAX_NAME_CHARS:
            raise CliError(f"--names: the name {short_repr(n)} has {len(n)} characters, at most {MAX_NAME_CHARS}")
        if not n.isprintable():
            raise CliError(f"--names: the name {short_repr(n)} holds a control character")
        check_text_path(n, "--names: the name")
    twice = next((n for i, n in enumerate(names) if n in names[:i]), None)
    if twice is not None:                # the second was silently renamed "NAME (2)"
        raise CliError(f"--names: the name {short_repr(twice)} is given twice; each run's row needs its own name")


def invocations_problem(run_path: Path) -> str | None:
    """What is wrong with a run folder's invocations.jsonl (a directory in its place, damaged
    lines), or None. It only says which code paths the episodes ran on: the report and diff read
    the records without it, but say so (a resume refuses a directory; it appends after damaged
    lines, which ``tasks.run_folder.read_invocations`` names and the rest skips)."""
    from tasks.run_folder import read_invocations

    path = run_path / "invocations.jsonl"
    if path.is_dir():
        return (f"{path} is a directory, where the log of the run's invocations belongs: the CPU code paths of its "
                f"episodes are unknown (a resume refuses the folder until it is moved away)")
    try:
        bad = read_invocations(run_path)[1]
    except OSError as exc:
        return f"{path} cannot be read ({exc.strerror or exc}): the CPU code paths of its episodes are unknown"
    if bad:
        shown = ", ".join(f"{path}:{n}" for n in bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        return (f"{shown}: damaged line{'s' if len(bad) > 1 else ''} of the run's invocation log (torn by a kill, "
                f"or edited), skipped: the CPU code paths shown come from the other lines")
    return None


def load_run(path: str | Path, name: str | None = None, warnings: list[str] | None = None) -> Run:
    """A run folder's finished episodes and summary; CliError when it is missing, unreadable or
    empty. Damaged lines of episodes.jsonl are skipped, each named as FILE:LINE in ``warnings``
    (also records of one episode that disagree, and records of episodes that are not the run's:
    ``tasks.run_folder.scan_results``); so are an unreadable config.yaml, records that disagree with it
    and a damaged invocations.jsonl."""
    from helios.schema import read_text, short_repr, yaml_load_text
    from tasks.run_folder import RunFolderError, run_cpu_models, run_cpu_paths, scan_results
    from tasks.trial_config import config_fingerprint, run_episode_ids
    from tasks.trial_summary import summarize
    from tools.cli import CliError

    warnings = warnings if warnings is not None else []
    p = Path(path)
    check_text_path(p, "run folder")
    if not p.exists():
        raise CliError(f"run folder {short_repr(str(p))} does not exist")
    if not p.is_dir():
        raise CliError(f"run folder {short_repr(str(p))} is a file, not a run folder")
    results = p / "episodes.jsonl"
    config: dict = {}
    config_warnings: list[str] = []
    cfg_path = p / "config.yaml"
    if cfg_path.exists():
        try:
            loaded = yaml_load_text(read_text(cfg_path, str(cfg_path), CliError), str(cfg_path), CliError)
            if loaded is not None and not isinstance(loaded, dict):
                raise CliError(f"{cfg_path} holds a {type(loaded).__name__}, not a trial config")
            config = loaded or {}
        except CliError as exc:
            config_warnings.append(f"{exc}; the run's configuration is shown as unknown")
    selected = run_episode_ids(config) if config else None      # the episodes its records may be of
    try:
        scan = scan_results(results, *(selected or (None,)))
    except RunFolderError as exc:
        raise CliError(str(exc)) from None
    for d in scan.damaged[:MAX_LISTED_DAMAGE]:
        warnings.append(f"{results}:{d.lineno}: {d.reason}; skipped this line")
    if len(scan.damaged) > MAX_LISTED_DAMAGE:
        warnings.append(f"{results}: {len(scan.damaged) - MAX_LISTED_DAMAGE} more damaged line(s) skipped")
    if scan.repeated_runs:
        shown = ", ".join(f"{eid} ({n} runs)" for eid, n in list(scan.repeated_runs.items())[:5])
        more = f" and {len(scan.repeated_runs) - 5} more" if len(scan.repeated_runs) > 5 else ""
        warnings.append(f"{results}: robot runs repeated under one episode id, the first of each is in the tables: "
                        f"{shown}{more} (on a robot, --trial-id gives each run its own id)")
    records = list(scan.records.values())
    if not records:
        what = "only damaged lines" if scan.damaged else "missing or empty"
        raise CliError(f"run folder {str(p)!r} has no finished episodes (episodes.jsonl {what}); "
                       f"run `python -m tools trials --out {p}` (or `tools spot`) first")
    records.sort(key=lambda r: r["episode_id"])
    warnings.extend(config_warnings)
    invocations = invocations_problem(p)
    if invocations:
        warnings.append(invocations)
    fps = scan.fingerprints() - {None}
    if len(fps) > 1:
        warnings.append(f"{results}: the records were made with {len(fps)} different configurations "
                        f"(fingerprints {', '.join(sorted(fps))}); they are reported together")
    elif fps and config:
        try:
            written = config_fingerprint(config)
        except (TypeError, ValueError):
            written = None
        if written not in fps:
            warnings.append(f"{cfg_path} does not describe the records in {results} (they were made with "
                            f"configuration {next(iter(fps))}, config.yaml says {written}): it was edited or "
                            f"replaced; the table shows the records")
    cpu = tuple(run_cpu_paths(p))
    if len(cpu) > 1:
        warnings.append(f"{p}: its episodes ran on {len(cpu)} different CPU code paths ({' | '.join(cpu)}); "
                        f"they can differ in outcome (README, \"One CPU code path\")")
    return Run(name or p.resolve().name, p, records, summarize(records), config, legacy=scan.legacy, cpu=cpu,
               cpu_models=tuple(run_cpu_models(p)))
