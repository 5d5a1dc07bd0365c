"""The leaderboard's columns are defined once, by the server's CSV
(``GET /api/v1/leaderboards/{task}/csv``): the client's ``Leaderboard.frame()``
has the same columns in the same order (without the board's own ``task`` and
``obs_type``, plus ``submission_ids``), and the same values row by row."""

import csv
import io
import math
from pathlib import Path

from conftest import REPO, run_server

from d3il_client import Client

BOARD_LEVEL = ["task", "obs_type"]
CLIENT_ONLY = ["submission_ids"]


def test_the_frame_has_the_server_csv_columns_and_values(client: Client, tmp_path: Path) -> None:
    for task in ("avoiding", "pushing"):
        text = client.download_csv(task, tmp_path / f"{task}.csv").read_text()
        table = list(csv.DictReader(io.StringIO(text)))
        header = next(csv.reader(io.StringIO(text)))
        frame = client.leaderboard(task).frame()
        assert header[: len(BOARD_LEVEL)] == BOARD_LEVEL, header
        assert list(frame.columns) == header[len(BOARD_LEVEL) :] + CLIENT_ONLY, (list(frame.columns), header)
        assert len(frame) == len(table) > 0
        for (_, row), line in zip(frame.iterrows(), table, strict=True):
            assert line["obs_type"] == "state"
            for col in header[len(BOARD_LEVEL) :]:
                mine, theirs = row[col], line[col]
                if theirs == "":
                    assert mine is None or (isinstance(mine, float) and math.isnan(mine)) or mine == "", (col, mine)
                elif isinstance(mine, float):
                    # the CSV writes 4 decimals
                    assert abs(mine - float(theirs)) <= 5e-5, (col, mine, theirs)
                else:
                    assert str(mine) == theirs or float(str(mine)) == float(theirs), (col, mine, theirs)


def test_zoo_rows_carry_their_data_source_in_the_frame_and_the_csv(tmp_path: Path) -> None:
    with run_server(tmp_path, "--zoo", str(REPO / "assets" / "zoo")) as server:
        client = Client(server.base, server.token)
        frame = client.leaderboard("pushing").frame()
        zoo = frame[frame.data_source.notna()]
        assert len(zoo) > 0, frame
        assert all(s.startswith("trained here on d3il demos") for s in zoo.data_source), zoo
        text = client.download_csv("pushing", tmp_path / "p.csv").read_text()
        from_csv = [r["data_source"] for r in csv.DictReader(io.StringIO(text)) if r["data_source"]]
        assert from_csv == list(zoo.data_source)
