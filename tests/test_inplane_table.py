"""The signed in-plane BRDF table (neuralbrdf.data.inplane_table): calibrated BRDF values at signed
``theta_i_signed, theta_r_signed``, told apart from GCMS raw by its header alone, read as the same
table as its spherical form, and accepted by every reader — ``nb.read``, a fit's ``data.path``, a
latent fit's ``data.sources``, ``plot``, ``to-rgb`` and a study profile."""

import numpy as np
import pytest

import neuralbrdf as nb
from neuralbrdf.cli.main import main as cli
from neuralbrdf.data.inplane_table import read_inplane_table, write_inplane_table
from neuralbrdf.data.loading import load_measurement, read_brdf_table
from neuralbrdf.data.table import BrdfTable, write_table
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_spherical
from neuralbrdf.lightning.run import main as train
from neuralbrdf.sources import virtual_measurement


@pytest.fixture(scope="module")
def gold():
    return virtual_measurement("gold", "DS2", 0.0, 0, 1)


def test_a_signed_table_reads_as_its_spherical_twin_sign_of_theta_i_kept(gold, tmp_path):
    write_inplane_table(gold, tmp_path / "signed.csv")
    write_table(gold, tmp_path / "spherical.csv")
    header = (tmp_path / "signed.csv").read_text().splitlines()[0]
    assert header.startswith("theta_i_signed,theta_r_signed,400,410,")
    signed, spherical = read_brdf_table(tmp_path / "signed.csv"), read_brdf_table(tmp_path / "spherical.csv")
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "values", "wavelengths"):
        np.testing.assert_array_equal(getattr(signed, name), getattr(spherical, name), err_msg=name)
    theta_i, theta_r = signed.inplane_angles()
    assert theta_i.min() < 0 < theta_i.max()  # the sign the Table 5.1 split needs
    np.testing.assert_array_equal(np.stack([theta_i, theta_r]), np.stack(gold.inplane_angles()))


def test_rgb_and_weight_columns_round_trip(tmp_path):
    theta_i, theta_r = np.array([-40.0, -10.0, 0.0, 25.0, 60.0]), np.array([-40.0, 30.0, -0.5, 25.0, -70.0])
    rgb = np.abs(np.sin(np.arange(15.0))).reshape(5, 3)
    table = BrdfTable(*inplane_to_spherical(theta_i, theta_r), rgb, weight=np.arange(1.0, 6.0))
    path = tmp_path / "rgb.csv"
    write_inplane_table(table, path)
    assert path.read_text().splitlines()[0] == "theta_i_signed,theta_r_signed,R,G,B,weight"
    back = read_inplane_table(path)
    np.testing.assert_array_equal(np.stack(back.inplane_angles()), np.stack([theta_i, theta_r]))
    np.testing.assert_array_equal(back.values, rgb)
    np.testing.assert_array_equal(back.weight, table.weight)


@pytest.mark.parametrize("header, problem", [
    ("theta_i,theta_r,R,G,B", "a table of calibrated BRDF values at signed in-plane angles names them "
                              "theta_i_signed, theta_r_signed"),
    ("theta_i,theta_r,400,410,420", "starts theta_i, theta_r like a GCMS raw file"),
])
def test_theta_i_theta_r_with_other_columns_is_neither_gcms_nor_guessed(tmp_path, header, problem):
    """The header says which format a file is: ``theta_i, theta_r`` is GCMS raw only with GCMS's
    own bands, and a file with BRDF columns under those names is refused, pointing at the signed
    table's names, whatever its values."""
    path = tmp_path / "t.csv"
    path.write_text(header + "\n" + "\n".join(f"{a},{a},{','.join(['0.5'] * (header.count(',') - 1))}"
                                              for a in (-30, 0, 30)) + "\n")
    for read in (lambda: nb.read(path), lambda: nb.read(path, tmp_path / "n9.csv"), lambda: read_brdf_table(path)):
        with pytest.raises(InputError) as caught:
            read()
        assert problem in str(caught.value) and str(caught.value).startswith(f"{path}, line 1")


def test_gcms_raw_still_asks_for_its_reference(tmp_path):
    from neuralbrdf.virtual.instrument import default_data_path

    with pytest.raises(InputError, match="is a GCMS raw file"):
        load_measurement(default_data_path("gold"))
    with pytest.raises(InputError, match="is a GCMS raw file"):
        read_brdf_table(default_data_path("gold"))
    lines = default_data_path("gold").read_text().splitlines()
    header = lines[0].split(",")
    (tmp_path / "gold.csv").write_text("\n".join([",".join(header[:2] + [f"{float(w):.1f}" for w in header[2:]]),
                                                *lines[1:]]) + "\n")  # 390.0, ...: the same bands
    assert load_measurement(tmp_path / "gold.csv", default_data_path("munsell_n9")).n_rows == 1001


@pytest.mark.parametrize("row, line_column, words", [
    ("95,20,1,1,1", (2, "theta_i_signed"), "angle 95° outside [-90, 90] degrees"),
    ("10,-91,1,1,1", (2, "theta_r_signed"), "angle -91° outside [-90, 90] degrees (polar angles are measured from"),
    ("10,20,1,-1,1", (2, "G"), "negative BRDF value -1"),
])
def test_bad_cells_name_the_line_and_the_signed_column(tmp_path, row, line_column, words):
    path = tmp_path / "t.csv"
    path.write_text(f"theta_i_signed,theta_r_signed,R,G,B\n{row}\n")
    with pytest.raises(InputError) as caught:
        read_inplane_table(path)
    line, column = line_column
    assert str(caught.value).startswith(f"{path}, line {line}, column {column!r}: {words}")


def test_a_repeated_geometry_is_named_in_signed_angles(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("theta_i_signed,theta_r_signed,R,G,B\n-10,20,1,1,1\n-10,20,1,2,1\n")
    with pytest.raises(InputError, match=r"line 3: repeated geometry \(theta_i_signed, theta_r_signed\) = "
                                         r"\(-10, 20\) with different values than line 2"):
        read_inplane_table(path)


def test_an_out_of_plane_table_is_not_written_as_in_plane(tmp_path):
    table = BrdfTable([30.0], [0.0], [30.0], [90.0], [[1.0, 1.0, 1.0]])
    with pytest.raises(InputError, match="out of the plane of incidence"):
        write_inplane_table(table, tmp_path / "t.csv")
    assert not (tmp_path / "t.csv").exists()


def test_every_reader_takes_a_signed_table(gold, tmp_path, capsys, monkeypatch):
    """nb.read, to-rgb (which writes the same format), plot, an ABC fit and a spectral MLP fit from
    data.path, a latent fit from data.sources, and a study profile's table."""
    monkeypatch.chdir(tmp_path)
    spectral, rgb = tmp_path / "gold.csv", tmp_path / "gold_rgb.csv"
    write_inplane_table(gold, spectral)
    assert nb.read(spectral).samples.n_rows == gold.n_rows
    assert cli(["to-rgb", str(spectral), "--out", str(rgb)]) == 0
    assert rgb.read_text().startswith("theta_i_signed,theta_r_signed,R,G,B\n")
    assert cli(["plot", str(rgb), "--out", "plot.png"]) == 0
    quiet = ["--trainer.enable_progress_bar", "false"]
    assert train(["fit", "--config", "abc", "--data.path", str(rgb), "--model.n_starts", "1", "--data.eval_plan",
                  "null", "--run_dir", "abc", *quiet]) == 0
    assert train(["fit", "--config", "spectral_mlp", "--data.path", str(spectral), "--trainer.max_epochs", "1",
                  "--run_dir", "mlp", *quiet]) == 0
    from neuralbrdf.lightning.latent_fit_data import LatentFitData

    data = LatentFitData(sources=[{"path": str(rgb)}, {"virtual": "cyan"}], eval_plan=None)
    data.setup()
    assert data.material_names == ["gold_rgb", "cyan"]
    from neuralbrdf.study.profile import load_profile

    (tmp_path / "p.yaml").write_text(
        "render: {spp: 1, resolution: 16}\ncost: {spp: 1, resolution: 16, repeats: 1, batch: 1024}\n"
        "materials:\n  - {name: mine, truth: virtual:gold, table: gold.csv}\n"
        "variants:\n  - {name: abc, method: abc, config: configs/abc.yaml}\n")
    assert load_profile(str(tmp_path / "p.yaml")).materials[0].is_spectral
