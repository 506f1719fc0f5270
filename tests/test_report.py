"""`tools report`: the paper-style table from run folders, the PNG plots and the HTML page."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tasks.run_folder import append_result, prepare_run_folder
from tasks.trial_config import TrialConfig
from tools.report import FIGURES, make_report


def _record(i: int, phases: int, reason: str | None, gpu: bool, collisions: int = 0) -> dict:
    """A synthetic episode record reaching the first ``phases`` of the five phases."""
    flags = [k < phases for k in range(5)]
    t = np.linspace(0, 60 + 10 * i, 12)
    series = {"t": t.round(2).tolist(), "rss_mb": (400 + 2 * t).round(2).tolist(),
              "map_mb": (5 + 0.1 * t).round(3).tolist()}
    if gpu:
        series["gpu_allocated_mb"] = (900 + 20 * t).round(2).tolist()
        series["gpu_reserved_mb"] = (1500 + 30 * t).round(2).tolist()
    return {"episode_id": f"val-{i:05d}", "agent": "x", "task": "Move the mug from the stool to the table",
            "seed": i, "success": flags[4], "error": None, "commands": 50, "limit_hit": False, "extra": {},
            "collision_events": [], "sim_time": float(t[-1]), "wall_time": 3.0,
            "metrics": {"find_obj": flags[0], "pick": flags[1], "find_rec": flags[2], "place": flags[3],
                        "success": flags[4], "collisions": collisions, "failure_reason": reason},
            "memory": {"peak_rss_mb": float(series["rss_mb"][-1]), "map_mb_peak": float(series["map_mb"][-1]),
                       "gpu_allocated_mb_peak": 2000.0 if gpu else None,
                       "gpu_reserved_mb_peak": 3000.0 if gpu else None, "series": series}}


def _make_run(path, outcomes, gpu=False):
    prepare_run_folder(path, TrialConfig(agent="oracle", split="val", episodes=len(outcomes)))
    for i, (phases, reason) in enumerate(outcomes):
        append_result(path / "episodes.jsonl", _record(i, phases, reason, gpu))
    return path


def test_report_on_two_runs_writes_the_table_pngs_and_html(tmp_path):
    from matplotlib.image import imread

    a = _make_run(tmp_path / "helios", [(5, None)] * 6 + [(4, "collision"), (2, "receptacle_not_found"),
                                                       (1, "pick_failed"), (0, "not_found")], gpu=True)
    b = _make_run(tmp_path / "trusting", [(5, None)] * 3 + [(3, "place_failed")] * 2 + [(0, "not_found")] * 5)
    result = make_report([a, b], tmp_path / "report")
    text, md = result["text"], result["markdown"]
    # FindObj 9/10, Pick 8/10, FindRec 7/10, Place 7/10, SR 6/10 for HELIOS
    assert "helios    90.0 ± 9.5   80.0 ± 12.6  70.0 ± 14.5  70.0 ± 14.5  60.0 ± 15.5" in text
    assert "| trusting | 50.0 ± 15.8 | 50.0 ± 15.8 | 50.0 ± 15.8 | 30.0 ± 14.5 | 30.0 ± 14.5 |" in md
    assert "| run | FindObj | Pick | FindRec | Place | SR |" in md
    saved = (tmp_path / "report" / "table.md").read_text()
    assert saved.startswith(md.strip())                   # then the warnings the terminal printed, if any
    assert saved.strip() == (md + "".join(f"\n- {w}" if i else f"\n\n**Warnings**\n\n- {w}"
                                          for i, w in enumerate(result["warnings"]))).strip()
    for name in FIGURES:
        png = tmp_path / "report" / name
        assert png.stat().st_size > 15_000, name
        img = imread(png)
        assert img.shape[0] > 200 and img.shape[1] > 400 and img[..., :3].std() > 0.05, name   # not blank
    html = result["html"].read_text()
    assert html.count("data:image/png;base64,") == len(FIGURES) == 4 and "<td>helios</td>" in html and "<td>trusting</td>" in html
    assert "GPU alloc MB" in text and "2000.0" in text


def test_report_on_real_runs_from_the_cli(tmp_path, capsys):
    """End to end on one real (short) oracle episode, in two folders under different names."""
    import shutil

    from helios.schema import with_overrides
    from tasks.episodes import load_split
    from tasks.trials import run_batch
    from tools.cli import main

    run = tmp_path / "oracle"
    run_batch(with_overrides(TrialConfig(episodes=1), ["runner.max_sim_time=20"]), load_split("smoke")[:1], run)
    shutil.copytree(run, tmp_path / "copy")             # one folder given twice is refused
    assert main(["report", str(run), str(tmp_path / "copy"), "--names", "a,b", "--out", str(tmp_path / "rep")]) == 0
    out = capsys.readouterr().out
    assert "| a |" in out and "| b |" in out and f"report: {tmp_path / 'rep' / 'index.html'}" in out
    from helios.runtime import cpu_dispatch

    assert "CPU code paths" in out and cpu_dispatch()["pin"] in out     # the paths its invocation ran on
    assert all((tmp_path / "rep" / f).stat().st_size > 10_000 for f in FIGURES)
    with pytest.raises(Exception, match="--names has 1 name"):
        make_report([run, run], tmp_path / "rep2", names=["only"])


def test_report_common_compares_runs_on_the_episodes_they_share(tmp_path):
    a = _make_run(tmp_path / "long", [(5, None)] * 4 + [(0, "not_found")] * 6)       # 10 episodes
    b = _make_run(tmp_path / "short", [(0, "not_found")] * 4)                          # val-00000..3
    plain = make_report([a, b], tmp_path / "plain")
    assert any("different numbers of episodes (4, 10)" in w for w in plain["warnings"])
    assert "| long | 40.0 ± 15.5 |" in plain["markdown"]
    shared = make_report([a, b], tmp_path / "shared", common=True)
    assert any("the 4 episode(s) all runs finished" in w for w in shared["warnings"])
    # both runs finished: trimmed to the shared 4, the 10-episode run is not "4 of its 10 finished" (audit)
    assert not any("episodes finished (a run in progress" in w for w in shared["warnings"]), shared["warnings"]
    assert "| long | 100.0 ± 0.0 | 100.0 ± 0.0 | 100.0 ± 0.0 | 100.0 ± 0.0 | 100.0 ± 0.0 |" in shared["markdown"]
    assert "| short | 0.0 ± 0.0 |" in shared["markdown"]
    # whatever the order: every run is trimmed, not only the first (metrics audit 2026-12-05)
    other_way = make_report([b, a], tmp_path / "other_way", common=True, episode_pages=False)
    assert "| long | 100.0 ± 0.0 | 100.0 ± 0.0 | 100.0 ± 0.0 | 100.0 ± 0.0 | 100.0 ± 0.0 |" in other_way["markdown"]


def test_report_names_what_each_run_changes_against_the_first(tmp_path):
    """A sensitivity sweep's rows (make sensitivity) are labelled by the setting each changed, read
    from the run folders; a row that changed more than meant shows every change."""
    from helios.schema import with_overrides
    from tools.report import SETTINGS_TITLE

    base = TrialConfig(agent="helios", split="val", episodes=2)
    paths = []
    for name, settings in (("paper", []), ("tau_g", ["helios.decision.tau_object=0.3"]), ("same", []),
                           ("two", ["helios.scoring.alpha_cs=2", "seed=3"]), ("no-config", [])):
        path = tmp_path / name
        prepare_run_folder(path, with_overrides(base, settings))
        for i, (phases, reason) in enumerate([(5, None), (0, "not_found")]):
            append_result(path / "episodes.jsonl", _record(i, phases, reason, False))
        paths.append(path)
    (tmp_path / "no-config" / "config.yaml").unlink()       # its agent is then the records' ("x")
    text = make_report(paths, tmp_path / "rep", episode_pages=False)["text"]
    table = text[text.index(SETTINGS_TITLE):].split("\n\n")[0].splitlines()
    rows = {line.split()[0]: line for line in table[3:]}
    assert list(rows) == ["paper", "tau_g", "same", "two", "no-config"]
    assert "(the first run" in rows["paper"] and [r.split()[1] for r in rows.values()] == ["helios"] * 4 + ["x"]
    assert rows["tau_g"].endswith("helios.decision.tau_object: 0.5 -> 0.3")
    assert rows["same"].endswith("nothing (the same configuration)")
    assert rows["two"].endswith("helios.scoring.alpha_cs: 1.0 -> 2.0; seed: 0 -> 3")
    assert rows["no-config"].endswith("unknown (a run folder without a readable config.yaml)")
    one = make_report(paths[:1], tmp_path / "one", episode_pages=False)["text"]
    assert SETTINGS_TITLE not in one, "one run: nothing to read it against"


def test_report_says_when_runs_share_no_episode_and_when_a_run_is_unfinished(tmp_path):
    a = _make_run(tmp_path / "a", [(5, None)] * 4)                                     # val-00000..3
    b = tmp_path / "b"
    prepare_run_folder(b, TrialConfig(agent="oracle", split="val", episodes=10))       # 3 of 10 done
    for i in range(6, 9):
        append_result(b / "episodes.jsonl", _record(i, 0, "not_found", False))
    warnings = make_report([a, b], tmp_path / "rep")["warnings"]
    assert any("the runs share no episode" in w and "no episode to pair" in w for w in warnings), warnings
    assert not any("--common compares them" in w for w in warnings), "--common would find nothing to compare"
    assert any(w.startswith("b: 3 of its 10 episodes finished") for w in warnings), warnings
    assert not any(w.startswith("a: ") for w in warnings), "a finished run is not flagged"


def test_sign_test_matches_the_binomial_tails_by_hand():
    from tools.report_stats import sign_test_p

    assert sign_test_p(0, 0) == 1.0
    assert sign_test_p(3, 3) == 1.0
    assert sign_test_p(5, 0) == pytest.approx(2 / 32)                 # 2 * 0.5^5
    assert sign_test_p(1, 14) == pytest.approx(2 * 16 / 2 ** 15)      # 2 * (C(15,0) + C(15,1)) / 2^15
    assert sign_test_p(2, 9) == sign_test_p(9, 2)


def test_p_values_below_one_percent_are_not_printed_as_zero():
    from tools.report_stats import p_text

    assert p_text(0.0004) == "p<0.01"
    assert p_text(0.0049) == "p<0.01"
    assert p_text(0.0051) == "p=0.01"
    assert p_text(0.56) == "p=0.56"
    # next to 0.05 a third decimal: +4 -13 (p = 0.049) is significant, 65 vs 44 (p = 0.055) is not;
    # both printed "p=0.05" (metrics audit 2026-12-05)
    from tools.report_stats import sign_test_p

    assert p_text(sign_test_p(4, 13)) == "p=0.049" and p_text(sign_test_p(65, 44)) == "p=0.055"
    assert p_text(0.0449) == "p=0.04" and p_text(0.0551) == "p=0.06"


def test_report_pairs_each_run_with_the_first_episode_by_episode(tmp_path):
    # episodes 0-3: both succeed; 4-5: only b finds the object; 6: only a succeeds; 7-9: both fail
    a = _make_run(tmp_path / "a", [(5, None)] * 4 + [(0, "not_found")] * 2 + [(5, None)] + [(0, "not_found")] * 3)
    b = _make_run(tmp_path / "b", [(5, None)] * 4 + [(1, "pick_failed")] * 2 + [(0, "not_found")] * 4)
    result = make_report([a, b], tmp_path / "rep", common=True)
    row = "| b | a | 10 | +2 -1 (p=1.00) | +0 -1 (p=1.00) | +0 -1 (p=1.00) | +0 -1 (p=1.00) | +0 -1 (p=1.00) |"
    assert row in result["markdown"]
    assert "Paired with a" in result["text"]
    assert "Paired with" not in make_report([a], tmp_path / "one")["text"]


def test_detectable_gap_is_the_smallest_net_count_the_sign_test_accepts():
    from tools.report_stats import detectable_gap, sign_test_p

    for discordant in range(0, 61):
        sig = [net for net in range(discordant % 2, discordant + 1, 2)
               if sign_test_p((discordant + net) // 2, (discordant - net) // 2) < 0.05]
        assert detectable_gap(discordant) == (sig[0] if sig else None)
    assert detectable_gap(5) is None and detectable_gap(6) == 6      # 6-0 is the first clean sweep below 0.05
    assert detectable_gap(46) == 16                                   # 31-15: p = 0.026 (30-16: 0.054)


def test_episodes_needed_is_where_the_gap_seen_would_first_reach_significance():
    from tools.report_stats import _sign_test_p_float, episodes_needed, sign_test_p

    assert _sign_test_p_float(17, 5) == pytest.approx(sign_test_p(17, 5))
    assert episodes_needed(20, 20, 200) is None                       # no gap: no number of episodes helps
    n = episodes_needed(26, 20, 200)                                  # +3 points, 23 % of episodes differ
    assert 900 < n < 1200
    at = lambda m: sign_test_p(round(26 * m / 200), round(20 * m / 200))
    assert at(n) < 0.05 and at(n - 10) >= 0.05
    assert episodes_needed(17, 5, 200) < 200                          # already significant at 200 (p = 0.02)
    assert episodes_needed(101, 100, 200, limit=10_000) is None       # beyond the limit


def test_report_says_how_many_episodes_a_paired_gap_needs(tmp_path):
    # 40 episodes: b finds the object in 10 that a misses and misses 2 that a finds
    a = _make_run(tmp_path / "a", [(5, None)] * 2 + [(0, "not_found")] * 10 + [(5, None)] * 8 + [(0, "not_found")] * 20)
    b = _make_run(tmp_path / "b", [(0, "not_found")] * 2 + [(1, "pick_failed")] * 10 + [(5, None)] * 8
                  + [(0, "not_found")] * 20)
    md = make_report([a, b], tmp_path / "rep")["markdown"]
    assert "How many episodes the paired comparisons need" in md
    # FindObj: +10 -2 = +20.0 points; 12 differ, and 10-2 (p = 0.04) is the smallest significant split,
    # a net of 8 = 20.0 points; 38 episodes (round(9.5) = 10 vs 2) would already have shown it.
    # SR: +0 -2 = -5.0 points; 2 differing episodes cannot be significant; 0-6 (p = 0.03) needs 110.
    assert "| b | a | 40 | +20.0 | 20.0 | 38 | -5.0 | none | 110 |" in md


def _with_times(path, times):
    """A run whose episode i reaches FindObj at times[i] seconds (None: never) and Pick 10 s later."""
    outcomes = [(2, "receptacle_not_found") if t is not None else (0, "not_found") for t in times]
    _make_run(path, outcomes)
    lines = (path / "episodes.jsonl").read_text().splitlines()
    out = []
    for line, t in zip(lines, times):
        r = json.loads(line)
        r["metrics"].update(find_obj_time=t, pick_time=None if t is None else t + 10.0, find_rec_time=None)
        out.append(json.dumps(r))
    (path / "episodes.jsonl").write_text("\n".join(out) + "\n")
    return path


def test_report_says_which_run_reached_each_phase_first(tmp_path):
    # both find the object in episodes 0-5, b earlier in 0-4 and later in 5; only a finds it in 6;
    # neither in 7; old records (no phase times) give n/a
    a = _with_times(tmp_path / "a", [100, 200, 300, 400, 500, 50, 80, None])
    b = _with_times(tmp_path / "b", [90, 150, 250, 350, 450, 60, None, None])
    old = _make_run(tmp_path / "old", [(2, "receptacle_not_found")] * 8)
    md = make_report([a, b, old], tmp_path / "rep")["markdown"]
    assert "How fast each run searches" in md
    assert "| a | 200 (7) | 210 (7) | - (0) | - | - |" in md            # median of 7 times; none reached FindRec
    assert "| b | 200 (6) | 210 (6) | - (0) | +5 -2 (p=0.45) | +5 -2 (p=0.45) |" in md   # 0-4 b; 5, 6 a
    assert "| old | n/a | n/a | n/a | n/a | n/a |" in md


def test_time_budgets_score_each_run_as_if_stopped_there(tmp_path):
    """The time-budget table: a phase counts within T when it was reached strictly before T (the
    runner takes no observation or command that would start at the cap); paired sign tests at each
    budget; the curve behind the plot; report.json; budgets beyond a run's cap are refused."""
    from tools.cli import CliError
    from tools.report import parse_budgets
    from tools.report_phase_times import BUDGET_PHASES, run_phase_times, budget_curve
    from tools.report_runs import load_run

    a = _with_times(tmp_path / "a", [100, 200, 300, 400, 500, 50, 80, None])
    b = _with_times(tmp_path / "b", [90, 150, 250, 350, 450, 60, None, None])
    old = _make_run(tmp_path / "old", [(2, "receptacle_not_found")] * 8)
    result = make_report([a, b, old], tmp_path / "rep", budgets=(100, 300, 600), episode_pages=False)
    md = result["markdown"]
    assert "| run | phase | within 100 s | within 300 s | within 600 s |" in md
    # a: FindObj at 50, 80 before 100 s (100 itself is not "before"); 50, 80, 100, 200 before 300 s
    assert "| a | FindObj | 25.0 | 50.0 | 87.5 |" in md
    assert "| a | Pick | 25.0 | 50.0 | 87.5 |" in md                       # 10 s after FindObj
    assert "| a | FindRec | 0.0 | 0.0 | 0.0 |" in md
    # b before 100 s: 90, 60 (a has 50, 80 there): +1 (episode 0) -1 (episode 6)
    assert "| b | FindObj | 25.0 +1 -1 (p=1.00) | 50.0 +1 -1 (p=1.00) | 75.0 +0 -1 (p=1.00) |" in md
    assert "| old | FindObj | n/a | n/a | n/a |" in md
    saved = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert saved["a"]["time_budgets"]["300"] == {"FindObj": 50.0, "Pick": 50.0, "FindRec": 0.0}
    assert saved["old"]["time_budgets"]["300"] == {}
    times = run_phase_times(load_run(a), BUDGET_PHASES[0][0])
    assert budget_curve(times, np.array([0.0, 50.0, 50.1, 100.0, 100.1, 600.0])).tolist() == \
        [0.0, 0.0, 12.5, 25.0, 37.5, 87.5]
    # the default: fifths of the cap (600 s here)
    md = make_report([a, b], tmp_path / "rep2", episode_pages=False)["markdown"]
    assert "| run | phase | within 120 s | within 240 s | within 360 s | within 480 s | within 600 s |" in md
    with pytest.raises(CliError, match="700 s is beyond run 'a''s cap of 600 s"):
        make_report([a, b], tmp_path / "rep3", budgets=(300, 700), episode_pages=False)
    assert parse_budgets(" 300, 60.5 ") == (60.5, 300.0) and parse_budgets("") == ()
    for text, message in (("60,x", "'x' is not a number"), ("0", "not a positive"), ("inf", "not a positive"),
                          ("5,5", "given twice"), (",".join(map(str, range(1, 14))), "at most 12")):
        with pytest.raises(CliError, match=message):
            parse_budgets(text)


def test_the_budget_plot_draws_each_runs_curve(tmp_path):
    """Content, not only a file: one step line per run and panel whose heights are the run's
    percent reached by each second, and a dotted line at each budget of the table."""
    from tools.report_phase_times import BUDGET_PHASES, run_phase_times, budget_curve
    from tools.report_plots import _pyplot, plot_budgets
    from tools.report_runs import load_run

    plt = _pyplot()
    runs = [load_run(_with_times(tmp_path / "a", [100, 200, None, None])),
            load_run(_with_times(tmp_path / "b", [50, None, None, None]))]

    class Keep:
        figure = None

        def __getattr__(self, name):
            return getattr(plt, name)

        def close(self, fig):
            Keep.figure = fig

    plot_budgets(runs, tmp_path / "b.png", Keep(), budgets=(150.0, 300.0))
    fig = Keep.figure
    assert (tmp_path / "b.png").stat().st_size > 10_000
    for ax, (key, name) in zip(fig.axes, BUDGET_PHASES):
        assert name in ax.get_title()
        solid = [ln for ln in ax.get_lines() if ln.get_linestyle() == "-"]
        dotted = sorted(float(ln.get_xdata()[0]) for ln in ax.get_lines() if ln.get_linestyle() == ":")
        assert dotted == [150.0, 300.0]
        assert len(solid) == 2
        for line, run in zip(solid, runs):
            x, y = np.asarray(line.get_xdata()), np.asarray(line.get_ydata())
            assert x[0] == 0.0 and x[-1] == 600.0
            assert np.array_equal(y, budget_curve(run_phase_times(run, key), x))
    # a's FindObj reaches 25 % after 100 s and 50 % after 200 s; b's 25 % after 50 s
    y_a = np.asarray(fig.axes[0].get_lines()[0].get_ydata())
    assert y_a[0] == 0.0 and y_a.max() == 50.0
    plt.close(fig)


@pytest.mark.parametrize("n_runs", [1, 3])
def test_plot_titles_and_labels_lie_inside_the_figure(tmp_path, n_runs):
    """Issue 20 item 3: the subtask plot's title was cut off at the left edge (an axes title
    centred over a narrow axes). Every title, axis label, bar label and legend entry of every
    plot must lie inside its figure."""
    import matplotlib.text

    from tools.report_plots import _pyplot, plot_budgets, plot_failures, plot_memory, plot_subtasks
    from tools.report_runs import load_run

    plt = _pyplot()
    runs = [load_run(_make_run(tmp_path / f"run{i}", [(5, None)] * 3 + [(2, "receptacle_not_found"), (0, "not_found")]))
            for i in range(n_runs)]

    class Keep:                     # plt, but close() keeps the figure for a look
        figure = None

        def __getattr__(self, name):
            return getattr(plt, name)

        def close(self, fig):
            Keep.figure = fig

    for fn in (plot_subtasks, plot_failures, plot_memory, plot_budgets):
        fn(runs, tmp_path / "x.png", Keep())
        fig = Keep.figure
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        texts = [fig._suptitle] if fig._suptitle is not None else []
        for ax in fig.axes:
            texts += [ax.title, ax.xaxis.label, ax.yaxis.label, *ax.texts]
            if ax.get_legend() is not None:
                texts += ax.get_legend().get_texts()
        for legend in fig.legends:
            texts += legend.get_texts()
        W, H = fig.bbox.width, fig.bbox.height
        for t in texts:
            if not isinstance(t, matplotlib.text.Text) or not t.get_visible() or not t.get_text():
                continue
            bb = t.get_window_extent(renderer)
            assert bb.x0 >= -0.5 and bb.y0 >= -0.5 and bb.x1 <= W + 0.5 and bb.y1 <= H + 0.5, \
                (fn.__name__, t.get_text(), bb, W, H)
        plt.close(fig)


def _with_attempts(path, attempts):
    """Rewrite a run's records with these grasp-attempt counts (one per episode, in order)."""
    results = path / "episodes.jsonl"
    records = [json.loads(line) for line in results.read_text().splitlines()]
    for r, n in zip(records, attempts):
        r["metrics"]["pick_attempts"] = n
    results.write_text("".join(json.dumps(r) + "\n" for r in records))
    return path


def test_limit_pick_attempts_zeroes_every_phase_of_episodes_over_the_limit():
    from tasks.trial_summary import limit_pick_attempts

    records = [_record(i, 5, None, False) for i in range(3)]
    for r, n in zip(records, (1, 2, 6)):
        r["metrics"]["pick_attempts"] = n
    one = limit_pick_attempts(records, 1)
    assert [r["metrics"]["success"] for r in one] == [True, False, False]
    assert not any(one[1]["metrics"][k] for k in ("find_obj", "pick", "find_rec", "place", "success"))
    assert one[1]["metrics"]["pick_attempts"] == 2 and one[1]["episode_id"] == "val-00001"   # the rest is kept
    assert [r["metrics"]["find_obj"] for r in limit_pick_attempts(records, 5)] == [True, True, False]
    assert [r["metrics"]["find_obj"] for r in limit_pick_attempts(records, 6)] == [True, True, True]  # == limit: kept
    assert all(r["metrics"]["success"] for r in records)                                              # not in place
    unscored = {**records[0], "metrics": None}
    assert limit_pick_attempts([unscored], 1) == [unscored]
    for bad in (0, -1, 1001, 1.5, True, "2"):
        with pytest.raises(ValueError, match="pick-attempt limit"):
            limit_pick_attempts(records, bad)


def test_report_scores_the_papers_pick_limited_rows(tmp_path):
    # a: 4 successes with 1, 1, 2, 6 grasp attempts, 6 failures; b: 2 successes with 1 attempt each
    a = _with_attempts(_make_run(tmp_path / "a", [(5, None)] * 4 + [(0, "not_found")] * 6), [1, 1, 2, 6])
    b = _with_attempts(_make_run(tmp_path / "b", [(5, None)] * 2 + [(0, "not_found")] * 8), [1, 1])
    result = make_report([a, b], tmp_path / "rep", pick_limits=(1, 5), episode_pages=False)
    md, text = result["markdown"], result["text"]
    assert "Percent of episodes ± standard error (unlimited pick attempts)" in text
    assert "| a | 40.0 ± 15.5 | 40.0 ± 15.5 | 40.0 ± 15.5 | 40.0 ± 15.5 | 40.0 ± 15.5 |" in md     # unlimited
    one = md.split("**1 pick (")[1].split("**5 picks (")[0]
    assert "such episodes: a 2, b 0" in one
    assert "| a | 20.0 ± 12.6 |" in one and "| b | 20.0 ± 12.6 |" in one                         # 2 of 10 each
    assert "| b | a | 10 | +0 -0 (p=1.00) |" in one             # same two successes on episodes 0 and 1
    five = md.split("**5 picks (")[1]
    assert "such episodes: a 1, b 0" in five and "| a | 30.0 ± 14.5 |" in five
    assert "| b | a | 10 | +0 -1 (p=1.00) |" in five
    assert md.index("**1 pick (") < md.index("**5 picks (") < md.index("**Runs**")
    saved = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert saved["a"]["pick_limits"]["1"]["SR"]["count"] == 2 and saved["a"]["pick_limits"]["5"]["SR"]["count"] == 3
    assert saved["a"]["summary"]["SR"]["count"] == 4
    plain = make_report([a, b], tmp_path / "plain", episode_pages=False)
    assert "picks" not in plain["text"] and "1 pick" not in plain["text"] and "unlimited" not in plain["text"]
    assert json.loads((tmp_path / "plain" / "report.json").read_text())["a"]["pick_limits"] == {}
    with pytest.raises(Exception, match="distinct integers"):
        make_report([a], tmp_path / "bad", pick_limits=(0,))


def test_report_pick_limits_from_the_cli(tmp_path, capsys):
    from tools.cli import main

    a = _with_attempts(_make_run(tmp_path / "a", [(5, None)] * 2 + [(0, "not_found")] * 2), [1, 3])
    assert main(["report", str(a), "--pick-limits", "2", "--no-episode-pages", "--out", str(tmp_path / "rep")]) == 0
    out = capsys.readouterr().out
    assert "2 picks (the paper's protocol: an episode with more than 2 grasp attempts scores 0" in out
    assert "| a | 25.0 ± 21.7 |" in out and "| a | 50.0 ± 25.0 |" in out


def test_the_reports_files_carry_the_warnings_the_terminal_printed(tmp_path):
    """(pictures audit 2026-12-05) `--common` reporting a run over 4 of its 8 episodes, runs of
    different lengths, damaged data: said on stderr only; index.html, table.txt and table.md
    showed the numbers without a word."""
    import html

    from cli_helpers import run_cli

    a = _make_run(tmp_path / "a", [(5, None), (5, None), (0, "not_found"), (5, None), (0, "not_found"), (5, None)])
    b = _make_run(tmp_path / "b", [(5, None), (0, "not_found"), (5, None), (5, None)])
    rc, out, err = run_cli(["report", str(a), str(b), "--out", str(tmp_path / "rep"), "--common"])
    assert rc == 0, err
    said = [line.removeprefix("warning: ") for line in err.splitlines() if line.startswith("warning: ")]
    assert any("compared on the 4 episode(s)" in w for w in said), err
    html_text = (tmp_path / "rep" / "index.html").read_text()
    for w in said:
        assert html.escape(w) in html_text, w
        assert f"warning: {w}" in (tmp_path / "rep" / "table.txt").read_text()
        assert f"- {w}" in (tmp_path / "rep" / "table.md").read_text()
    assert "<h2>How episodes ended (share of all episodes)</h2>" in html_text          # not the file's stem


def test_unscored_episodes_have_their_own_count_and_colour():
    """(pictures audit) An episode without metrics was a grey bar in failures.png (the grey of
    receptacle_not_found) and no column of the counts table, whose row then fell short."""
    from types import SimpleNamespace

    from tasks.metrics import FAILURE_REASONS
    from tools.report import failure_rows

    runs = [SimpleNamespace(name="r", summary={"episodes": 4, "scored": 3, "SR": {"count": 1},
                                               "failure_reasons": {k: 0 for k in FAILURE_REASONS} | {"pick_failed": 2}})]
    headers, rows = failure_rows(runs)
    assert headers[-1] == "unscored" and rows[0][-1] == 1
    assert sum(rows[0][1:]) == 4
    clean = SimpleNamespace(name="c", summary={"episodes": 2, "scored": 2, "SR": {"count": 1},
                                               "failure_reasons": {k: 0 for k in FAILURE_REASONS} | {"pick_failed": 1}})
    headers, rows = failure_rows([*runs, clean])             # mixed runs: every row as long as the headers
    assert all(len(row) == len(headers) for row in rows) and rows[1][-1] == 0 and sum(rows[1][1:]) == 2
