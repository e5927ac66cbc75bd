"""gsa quote (numbers in pages rewritten from the tables) and gsa published (flat
PPO against a published table, scored as it is), on fabricated tables: nothing to compile."""

import csv

import pytest

from gsa_jax.analysis.quoting import published, quote
from gsa_jax.commands import published as published_command
from gsa_jax.commands import quote as quote_command

RUNS = [("mlp", "", 0, 3952.6, 1500.0), ("mlp", "", 1, 1176.4, 2500.0), ("mixture", "3", 0, 4575.5, 4000.0),
        ("mixture", "3", 1, 4840.0, 4200.0), ("mixture", "24", 0, 3165.2, 2900.0)]


def write_csv(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


@pytest.fixture
def results(tmp_path):
    """A page's directory with a per_run_scores.csv and a final_returns.csv as gsa_jax.plot writes them."""
    (tmp_path / "results").mkdir()
    write_csv(tmp_path / "results" / "per_run_scores.csv", [
        {"env": "HalfCheetah-v5", "policy": p, "K": k, "seed": s, "score_kind": "deterministic", "final_score": score,
         "training_return_last_100_episodes": train} for p, k, s, score, train in RUNS])
    cell = {"env": "Hopper-v5", "K_over_action_dim": "", "seeds": 10, "final_return_mean": 3066.6, "ci95_halfwidth": 310.2,
            "iqm": 3195.0, "iqm_ci_low": 2785.4, "iqm_ci_high": 3317.0, "p_better_than_flat_ppo": "", "p_ci_low": "",
            "p_ci_high": "", "training_return_mean": 2605.0, "training_ci95_halfwidth": 220.0, "curve_iqm": 2460.2}
    write_csv(tmp_path / "results" / "final_returns.csv", [
        dict(cell, policy="mlp", K=""),
        dict(cell, policy="mixture", K=2, K_over_action_dim=0.667, iqm=2700.0, p_better_than_flat_ppo=0.314,
             p_ci_low=0.08, p_ci_high=0.556)])
    return tmp_path


def test_quoted_numbers_are_rewritten_from_the_tables(results):
    page = results / "README.md"
    per_run = "results/per_run_scores.csv env=HalfCheetah-v5"
    page.write_text(
        f"Flat PPO <!-- quote scores {per_run} policy=mlp -->1,176 / 1,693<!-- /quote -->; the weakest mixture run\n"
        f"<!-- quote min {per_run}\n  policy=mixture -->3,104<!-- /quote -->, K = 3 and 24 "
        f"<!-- quote range {per_run} K=3,24 -->?<!-- /quote -->, P <!-- quote value results/final_returns.csv "
        "policy=mixture col=p_better_than_flat_ppo digits=2 -->0.31<!-- /quote -->, flat PPO <!-- quote value "
        "results/final_returns.csv policy=mlp col=final_return_mean pm=ci95_halfwidth -->3,000<!-- /quote -->.\n\n"
        "<!-- quote table results/final_returns.csv -->\nold table\n<!-- /quote -->\n")
    assert quote_command.main([str(page), "--check"]) == 1  # stale, and left as it was
    assert "3,104" in page.read_text()
    assert quote_command.main([str(page)]) == 0
    text = page.read_text()
    assert "policy=mlp -->1,176 / 3,953<!-- /quote -->" in text  # each run's score, ascending
    assert "policy=mixture -->3,165<!-- /quote -->" in text and "K=3,24 -->3,165-4,840<!-- /quote -->" in text
    assert "digits=2 -->0.31<!-- /quote -->" in text and "pm=ci95_halfwidth -->3,067 ± 310<!-- /quote -->" in text
    assert "| flat PPO (MLP 64x64) | 3,067 ± 310 | 3,195 [2,785, 3,317] |  | 2,605 ± 220 | 2,460 |" in text
    assert "| K = 2 (0.67 d_a) | 3,067 ± 310 | 2,700 [2,785, 3,317] | 0.31 [0.08, 0.56] |" in text
    assert text.startswith("Flat PPO <!-- quote") and "| Hopper-v5 (d_a = 3) |" in text
    assert quote_command.main([str(page), "--check"]) == 0  # now current
    page.write_text(f"<!-- quote scores {per_run} policy=mlp order=file -->x<!-- /quote -->")
    quote_command.main([str(page)])
    assert "order=file -->3,953 / 1,176<!-- /quote -->" in page.read_text()  # seed order


def test_numbers_are_written_as_the_pages_write_them():
    assert quote.fmt(0.205, 2) == "0.21" and quote.fmt(0.185, 2) == "0.19" and quote.fmt(-1234.5) == "-1,235"
    assert quote.fmt(4565.46) == "4,565" and quote.fmt("") == "n/a" and quote.fmt(float("nan")) == "n/a"


def test_table_half_widths_under_ten_keep_a_decimal():
    assert quote.halfwidth(0.84) == "0.8" and quote.halfwidth(9.94) == "9.9" and quote.halfwidth(554.0) == "554"


def test_a_quote_that_matches_nothing_or_names_no_file_is_an_error(results, capsys):
    page = results / "README.md"
    for span in ("value results/per_run_scores.csv policy=mlp", "min results/per_run_scores.csv env=Ant-v5",
                 "scores results/missing.csv", "min results/per_run_scores.csv col=nope", "mean results/per_run_scores.csv"):
        page.write_text(f"<!-- quote {span} -->x<!-- /quote -->")
        assert quote_command.main([str(page)]) == 2
        assert capsys.readouterr().err.startswith("gsa quote: error: ")
        assert page.read_text().endswith("x<!-- /quote -->")  # nothing written


def test_a_value_with_spaces_is_quoted(tmp_path):
    (tmp_path / "aggregate.csv").write_text("config,normalized_iqm,lo,hi\nflat PPO,0.971,0.9,1\nK = 0.5 d_a,1.073,0.983,1.157\n")
    page = tmp_path / "README.md"
    page.write_text('<!-- quote value aggregate.csv config="K = 0.5 d_a" col=normalized_iqm ci=lo,hi digits=2 -->x<!-- /quote -->')
    assert quote_command.main([str(page)]) == 0 and "-->1.07 [0.98, 1.16]<!-- /quote -->" in page.read_text()


def test_median_of_the_matching_rows(tmp_path):
    (tmp_path / "t.csv").write_text("env,x\na,1\na,5\na,2\nb,100\n")
    page = tmp_path / "README.md"
    page.write_text('<!-- quote median t.csv env=a col=x -->?<!-- /quote --> <!-- quote median t.csv col=x digits=1 -->?<!-- /quote -->')
    assert quote_command.main([str(page)]) == 0 and page.read_text().count("-->2<!--") == 1 and "-->3.5<!--" in page.read_text()


def test_text_of_one_row(tmp_path):
    (tmp_path / "s.csv").write_text("env,margin,smallest_sufficient_K,undecided_below\na,0.1,2,1\na,0.2,,\n")
    page = tmp_path / "README.md"
    page.write_text('<!-- quote text s.csv margin=0.1 col=smallest_sufficient_K -->?<!-- /quote --> '
                    '<!-- quote text s.csv margin=0.2 col=undecided_below -->?<!-- /quote -->')
    assert quote_command.main([str(page)]) == 0 and "-->2<!--" in page.read_text() and "-->none<!--" in page.read_text()


def test_spread_is_mean_and_population_std_over_seeds(results):
    page = results / "README.md"
    page.write_text("<!-- quote spread results/per_run_scores.csv policy=mixture K=3 "
                    "col=training_return_last_100_episodes -->?<!-- /quote -->")
    quote_command.main([str(page)])
    assert "-->4,100 ± 100<!-- /quote -->" in page.read_text()  # 4,000 and 4,200: std with ddof 0


def test_flat_ppo_is_compared_with_the_published_task_of_the_same_name(results, tmp_path):
    ref = tmp_path / "reference.csv"
    write_csv(ref, [{"env": "HalfCheetah-v4", "mean": 1442.64, "std": 46.03, "source": "docs"},
                    {"env": "Humanoid-v4", "mean": 716.11, "std": 49.08, "source": "docs"}])
    out = tmp_path / "comparison.csv"
    assert published_command.main([str(ref), str(results / "results" / "per_run_scores.csv"), "--out", str(out)]) == 0
    with open(out) as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 1 and rows[0]["env"] == "HalfCheetah-v5" and rows[0]["published_env"] == "HalfCheetah-v4"
    assert (float(rows[0]["last_100_episodes_mean"]), float(rows[0]["last_100_episodes_std"])) == (2000.0, 500.0)
    assert float(rows[0]["deterministic_mean"]) == pytest.approx(2564.5) and rows[0]["seeds"] == "2"
    assert published.task_name("hopper") == published.task_name("Hopper-v4") != published.task_name("Hopper2-v4")
    write_csv(ref, [{"env": "Pusher-v4", "mean": -40.38, "std": 7.15, "source": "docs"}])
    assert published_command.main([str(ref), str(results / "results" / "per_run_scores.csv"), "--out", str(out)]) == 2
