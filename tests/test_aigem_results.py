"""An evaluation's results as data: the paper's table in the rows' keys."""

from __future__ import annotations

from aigem.evaluation.results import PAPER_TABLE, paper_rows
from aigem.metrics import table_columns


def test_paper_rows_hold_the_papers_numbers_in_the_keys_of_evaluates_rows() -> None:
    rows = paper_rows()
    assert list(rows) == list(PAPER_TABLE)
    # every row of the paper's Table 1, in its order
    assert [name.removesuffix(" (paper)") for name in rows] == [
        "CS-LSTM",
        "GRIP++",
        "STA-LSTM",
        "DeepTrack",
        "GSTCN",
        "AiGem",
    ]
    assert rows["GRIP++ (paper)"]["params_k"] == 496 and rows["GRIP++ (paper)"]["fde_m"] is None
    assert rows["STA-LSTM (paper)"]["rmse_5s_m"] == 3.78
    assert rows["DeepTrack (paper)"]["ade_m"] == 2.01
    assert rows["AiGem (paper)"] == {
        "ade_m": 1.42,
        "fde_m": 2.57,
        "params_k": 74.5,
        "rmse_1s_m": 0.61,
        "rmse_2s_m": 1.02,
        "rmse_3s_m": 1.27,
        "rmse_4s_m": 1.84,
        "rmse_5s_m": 1.95,
    }
    assert rows["GSTCN (paper)"]["fde_m"] is None
    # every column of the table over 5 s finds its number
    assert all(key in rows["CS-LSTM (paper)"] for key, _ in table_columns(5))
