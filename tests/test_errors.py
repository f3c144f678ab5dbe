"""The readers of a run directory, store and export say what went wrong: a missing artifact raises
:class:`~prt_torch.errors.MissingArtifact`, a stale one :class:`~prt_torch.errors.StaleArtifact`, a damaged one
:class:`~prt_torch.errors.DamagedArtifact` (all :class:`~prt_torch.errors.PrtError`, same one-line messages)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from prt_torch.errors import ArtifactError, DamagedArtifact, MissingArtifact, PrtError, StaleArtifact
from prt_torch.rundir import RunDir
from tests.export.pipeline import build_tiny_run, copy_run


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_tiny_run(tmp_path_factory.getbasetemp())


def test_subclasses_of_prt_error() -> None:
    for cls in (MissingArtifact, StaleArtifact, DamagedArtifact):
        assert issubclass(cls, ArtifactError) and issubclass(cls, PrtError)


def test_missing_run_files(tmp_path: Path) -> None:
    with pytest.raises(MissingArtifact, match="run directory not found"):
        RunDir(tmp_path / "nope").require()
    run = RunDir(tmp_path)
    for read, text in ((run.dataset, "no dataset in"), (run.character, "no character in"),
                       (run.model_meta, "model metadata not found"), (run.export_meta, "is not exported"),
                       (run.transfer_meta, "no learned transfer")):
        with pytest.raises(MissingArtifact, match=text):
            read()
    with pytest.raises(MissingArtifact, match="file not found"):
        run.read_json(tmp_path / "absent.json")


def test_damaged_json_and_stage_keys(tmp_path: Path) -> None:
    run = RunDir(tmp_path)
    run.stages_json.write_text("{not json")
    with pytest.raises(DamagedArtifact, match="not valid JSON"):
        run.stage_keys()
    run.begin("train")  # a damaged stages.json only means that nothing is up to date
    assert run.stage_keys() == {}
    run.model_json.write_text("[1, 2]")
    with pytest.raises(DamagedArtifact, match="expected a JSON object"):
        run.model_meta()


def test_dataset_missing_damaged_chunks(synthetic_dataset: Path, tmp_path: Path) -> None:
    from prt_torch.bake.store import BakedDataset, open_dataset

    with pytest.raises(MissingArtifact, match="dataset not found"):
        open_dataset(tmp_path / "none.zarr")
    (tmp_path / "junk.zarr").mkdir()
    with pytest.raises(DamagedArtifact):
        BakedDataset(tmp_path / "junk.zarr")
    path = shutil.copytree(synthetic_dataset, tmp_path / "dataset.zarr")
    sorted(p for p in (path / "visibility" / "c").rglob("*") if p.is_file())[0].unlink()
    with pytest.raises(DamagedArtifact, match="missing chunk"):
        BakedDataset(path).split("train")
    import zarr

    g = zarr.open_group(str(path), mode="r+")
    held = BakedDataset(path).heldout_mask
    g["done"][held] = False
    with pytest.raises(MissingArtifact, match="has no baked frames"):
        BakedDataset(path).split("heldout")


def test_npz_and_rpo_files(tmp_path: Path) -> None:
    from prt_torch.brdf.rpo import RPO, RPO_FORMAT_VERSION
    from prt_torch.io import read_npz_with_meta

    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"garbage")
    with pytest.raises(MissingArtifact, match="character file not found"):
        read_npz_with_meta(tmp_path / "none.npz", "character")
    with pytest.raises(DamagedArtifact, match="not a character .npz file"):
        read_npz_with_meta(bad, "character")
    with pytest.raises(MissingArtifact, match="RPO file not found"):
        RPO.load(tmp_path / "none.npz")
    with pytest.raises(DamagedArtifact, match="not an RPO file"):
        RPO.load(bad)
    old = tmp_path / "old.npz"
    np.savez(old, u=np.zeros((4, 4)), w=np.zeros(4), tint=np.zeros(3),
             meta=np.array([RPO_FORMAT_VERSION + 99, 2, 0, 0]), name=np.array("x"))
    with pytest.raises(StaleArtifact, match="unsupported RPO file version"):
        RPO.load(old)
    np.savez(old, u=np.full((4, 4), np.nan), w=np.zeros(4), tint=np.zeros(3),
             meta=np.array([RPO_FORMAT_VERSION, 2, 0, 0]), name=np.array("x"))
    with pytest.raises(DamagedArtifact, match="RPO factors"):
        RPO.load(old)


def test_model_payloads(tmp_path: Path) -> None:
    torch = pytest.importorskip("torch")
    from prt_torch.models.visibility import read_payload

    with pytest.raises(MissingArtifact, match="model file not found"):
        read_payload(tmp_path / "none.pt", ("prt_torch.visibility_model/2",))
    (tmp_path / "junk.pt").write_bytes(b"garbage")
    with pytest.raises(DamagedArtifact, match="not a prt_torch model file"):
        read_payload(tmp_path / "junk.pt", ("prt_torch.visibility_model/2",))
    torch.save({"format": "prt_torch.visibility_model/0"}, tmp_path / "old.pt")
    with pytest.raises(StaleArtifact, match="format 'prt_torch.visibility_model/0'"):
        read_payload(tmp_path / "old.pt", ("prt_torch.visibility_model/2",))
    torch.save({"format": "someone.else/1"}, tmp_path / "foreign.pt")
    with pytest.raises(DamagedArtifact, match="format 'someone.else/1'"):
        read_payload(tmp_path / "foreign.pt", ("prt_torch.visibility_model/2",))


def test_exported_run_missing_stale_damaged(tiny_run: Path, tmp_path: Path) -> None:
    from prt_torch.player.bundle import RunBundle

    run = RunDir(copy_run(tiny_run, tmp_path / "run"))
    meta = run.export_meta()
    # damaged: a graph that is not the file export.json records
    graph = run.graph_path("visibility")
    saved = graph.read_bytes()
    graph.write_bytes(saved + b"x")
    with pytest.raises(DamagedArtifact, match="sha256 differs"):
        run.export_meta()
    graph.unlink()
    with pytest.raises(DamagedArtifact, match="visibility.onnx is missing"):
        run.export_meta()
    graph.write_bytes(saved)
    # stale: the model the export was made from changed since (re-trained)
    model = run.inside(meta["model_file"])
    model_json = json.loads(run.model_json.read_text())
    model.write_bytes(model.read_bytes() + b"x")
    with pytest.raises(StaleArtifact, match="is stale"):
        RunBundle(run, graphs=())
    assert model_json  # model.json still lists the old hash: the train unit itself is damaged now
    with pytest.raises(DamagedArtifact, match="is not the file it records"):
        run.model_meta()
    # stale: another character than the one the run was made for
    with pytest.raises(StaleArtifact, match="is not the character this run was made for"):
        run.character(expect_hash="0" * 64)
    # missing
    run.export_json.unlink()
    with pytest.raises(MissingArtifact, match="is not exported"):
        run.export_meta()


def test_damaged_store_chunk_checksum(tiny_run: Path, tmp_path: Path) -> None:
    from prt_torch.bake.store import BakedDataset

    run = RunDir(copy_run(tiny_run, tmp_path / "run"))
    chunk = sorted(p for p in (run.dataset_path / "visibility").rglob("*") if p.is_file() and p.name != "zarr.json")[0]
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0xFF
    chunk.write_bytes(bytes(data))
    ds = BakedDataset(run.dataset_path)
    with pytest.raises(DamagedArtifact):
        ds.rows(ds.split_rows("train"), ("visibility",))
