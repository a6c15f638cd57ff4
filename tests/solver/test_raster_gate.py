"""The raster gate (solver/raster_gate.py): what it opens, what it refuses, and that what it
refuses is never read.

The rasters are real: the Pleiades crop of tests/data/matching (GeoTIFF with its _RPC.TXT) and
files written here; "another user's raster" is a copy of it in a sibling folder, watched with
inotify (tests/utils/leak_probes.py) so that a single open or read of it fails the test; the network
is a local listener counting the connections it receives.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from utils.leak_probes import CountingListener, FileWatch

from solver import raster_gate as gate
from solver.raster_gate import RasterLimits, RasterRefused, RasterSpace, create_raster, open_raster

DATA = Path(__file__).resolve().parents[1] / "data" / "matching"
LEFT = DATA / "ventoux_left.tif"


@pytest.fixture()
def root(tmp_path: Path) -> Path:
    """An image root: alice's folder with a real raster and its RPC sidecar, bob's secret, and
    a sibling folder ``alice2`` whose name starts with ``alice``."""
    r = tmp_path / "images"
    for user in ("alice", "bob", "alice2"):
        (r / user).mkdir(parents=True)
    shutil.copyfile(LEFT, r / "alice" / "a.tif")
    shutil.copyfile(DATA / "ventoux_left_RPC.TXT", r / "alice" / "a_RPC.TXT")
    shutil.copyfile(LEFT, r / "bob" / "secret.tif")
    shutil.copyfile(LEFT, r / "alice2" / "x.tif")
    return r


def _alice(root: Path, **limits: int) -> RasterSpace:
    return RasterSpace.of(root / "alice", limits=RasterLimits(**limits))


def _refused(code: str, fn, *args, **kwargs) -> RasterRefused:
    with pytest.raises(RasterRefused) as info:
        fn(*args, **kwargs)
    assert info.value.code == code, info.value.message
    return info.value


def _vrt(source: str, size: int = 10) -> str:
    return (f'<VRTDataset rasterXSize="{size}" rasterYSize="{size}"><VRTRasterBand dataType="UInt16" band="1">'
            f"<SimpleSource><SourceFilename>{source}</SourceFilename></SimpleSource></VRTRasterBand></VRTDataset>")


def test_a_geotiff_in_the_users_folder_opens_with_its_rpc_sidecar_when_asked(root):
    space = _alice(root)
    real = space.resolve("a.tif")
    with open_raster(real, space, sidecars=gate.RPC_SIDECARS) as r:
        assert (r.header.driver, r.header.width, r.header.height, r.header.dtype) == ("GTiff", 500, 500, "uint16")
        assert r.header.has_rpc and r.dataset.rpcs is not None
        assert r.dataset.read(1, window=((0, 4), (0, 4))).shape == (4, 4)
        private = Path(r.gdal_name).parent
        assert private.is_dir() and sorted(p.name for p in private.iterdir()) == ["a.tif", "a_RPC.TXT"]
    assert not private.exists()  # the private folder goes with the raster
    with open_raster(real, space) as r:  # no sidecar asked: GDAL does not see it
        assert not r.header.has_rpc


def test_the_watch_sees_a_read(root):
    """The inotify probe has teeth: a plain read of bob's raster is seen."""
    secret = root / "bob" / "secret.tif"
    with FileWatch(secret) as w:
        secret.read_bytes()[:10]
        assert {e for _p, e in w.events()} == {"open", "read"}


def test_a_vrt_naming_another_users_raster_is_refused_unread(root):
    """A VRT is not an allowed format, whatever it names: refused as a format before anything
    it names is looked at; bob's raster is neither opened nor read, and a VRT naming a missing
    file gets the same answer (existence cannot be probed)."""
    secret = root / "bob" / "secret.tif"
    (root / "alice" / "v.tif").write_text(_vrt(str(secret)))
    (root / "alice" / "m.vrt").write_text(_vrt(str(root / "bob" / "missing.tif")))
    space = _alice(root)
    with FileWatch(secret) as w:
        a = _refused("unsupported_format", open_raster, space.resolve("v.tif"), space, shown="v")
        b = _refused("unsupported_format", open_raster, space.resolve("m.vrt"), space, shown="v")
        assert w.events() == []
    assert a.message == b.message and "GeoTIFF" in a.message


def test_sidecars_beside_a_raster_are_never_read(root):
    """An external overview (``.ovr``, here a VRT naming bob's raster) and a ``.aux.xml``
    beside alice's GeoTIFF: plain GDAL reads both (bob's raster is opened); through the gate
    neither is seen, even by a decimated read that would use the overview."""
    import rasterio

    secret = root / "bob" / "secret.tif"
    b = root / "alice" / "b.tif"
    shutil.copyfile(LEFT, b)
    (root / "alice" / "b.tif.ovr").write_text(_vrt(str(secret), 250))
    (root / "alice" / "b.tif.aux.xml").write_text("<PAMDataset><SRS>EPSG:4326</SRS><GeoTransform>0,1,0,0,0,-1</GeoTransform></PAMDataset>")
    (root / "alice" / "b.tif.msk").write_text(_vrt(str(secret), 500))
    with FileWatch(secret) as w, rasterio.Env(GDAL_DISABLE_READDIR_ON_OPEN="FALSE", GDAL_PAM_ENABLED="YES", GDAL_GEOREF_SOURCES="PAM,INTERNAL"):
        with rasterio.open(b) as ds:  # the attack, without the gate
            assert ds.overviews(1) == [2] and ds.crs is not None
            ds.read(1, out_shape=(250, 250))
        assert w.events(), "plain GDAL should have read bob's raster through the .ovr"
    space = _alice(root)
    with FileWatch(secret) as w:
        with open_raster(space.resolve("b.tif"), space) as r:
            assert r.dataset.overviews(1) == [] and r.dataset.crs is None
            r.dataset.read(1, out_shape=(250, 250))
            r.dataset.read_masks(1)
        assert w.events() == []


def test_links_and_names_that_leave_the_folder_are_refused_alike(root, tmp_path):
    """The sibling folder ``alice2`` (a text ``startswith`` would take it for alice's), links
    out to an existing and to a missing file, absolute names and ``..``: refused before opening,
    with one sentence for existing and missing targets."""
    space = _alice(root)
    a = root / "alice"
    os.symlink("../alice2/x.tif", a / "sib.tif")
    os.symlink(root / "bob" / "secret.tif", a / "bobs.tif")
    os.symlink(root / "bob" / "nothing-here.tif", a / "ghost.tif")
    os.symlink(root / "bob", a / "bobdir")
    os.symlink("/etc/passwd", a / "passwd.tif")
    with FileWatch(root / "bob" / "secret.tif", root / "alice2" / "x.tif") as w:
        messages = {name: _refused("outside_space", space.resolve, name, shown="x").message
                    for name in ("sib.tif", "bobs.tif", "ghost.tif", "bobdir/secret.tif", "passwd.tif")}
        assert len(set(messages.values())) == 1, messages
        for name in ("../bob/secret.tif", "/etc/passwd", str(root / "bob" / "secret.tif"), "~bob/x.tif", "..\\bob\\x.tif", "C:x.tif"):
            _refused("invalid_name", space.resolve, name)
        # an absolute path outside the space given to open_raster itself
        _refused("outside_space", open_raster, root / "bob" / "secret.tif", space)
        _refused("outside_space", open_raster, root / "alice2" / "x.tif", space)
        assert w.events() == []
    os.symlink("a.tif", a / "inside.tif")  # a link inside the folder is fine
    assert space.resolve("inside.tif") == (a / "a.tif").resolve()
    assert space.contains(a / "sub" / "x.tif") and not space.contains(root / "alice2" / "x.tif") and not space.contains(a)


@pytest.mark.parametrize("name", ["x\0y.tif", "x\ny.tif", "x\x7f.tif", "a" * 256 + ".tif", "d/" * 600 + "x.tif", "\ud800.tif", "", "."])
def test_names_the_file_system_must_not_see(root, name):
    """NUL, control characters, a component over NAME_MAX, an over-long name, text that is
    not UTF-8, empty names: refused as text (invalid_name), never handed to the OS."""
    _refused("invalid_name", _alice(root).resolve, name)


def test_special_files_are_refused_without_blocking(root):
    """A FIFO (a read would wait for a writer forever), a directory, a missing file."""
    a = root / "alice"
    os.mkfifo(a / "fifo.tif")
    (a / "dir.tif").mkdir()
    space = _alice(root)
    out: list[str] = []

    def probe() -> None:
        for name in ("fifo.tif", "dir.tif"):
            try:
                open_raster(a / name, space)
            except RasterRefused as exc:
                out.append(exc.code)

    t = threading.Thread(target=probe, daemon=True)
    t.start()
    t.join(10)
    assert out == ["not_a_file", "not_a_file"]
    _refused("not_found", space.resolve, "none.tif")


@pytest.mark.parametrize("path", ["/vsicurl/http://127.0.0.1:9/x.tif", "/vsimem/x.tif", "/VSIZIP/a.zip/x.tif", "http://127.0.0.1:9/x.tif",
                                  "NITF_IM:0:/tmp/x.ntf", "GTIFF_DIR:1:/tmp/x.tif"])
def test_only_plain_local_files(path):
    _refused("invalid_name", open_raster, path, gate.LOCAL)


def test_gdal_sends_no_request_with_the_gates_options(tmp_path):
    """In a fresh process, ``/vsicurl/`` (directly and through a VRT) and a CRS given as a URL
    reach a local listener without the gate's options (the test's teeth) and not with them."""
    script = tmp_path / "fetch.py"
    script.write_text(
        "import sys, rasterio\n"
        "url, vrt = sys.argv[1], sys.argv[2]\n"
        "source = '/vsicurl/' + url + '/x.tif'\n"
        "open(vrt, 'w').write('<VRTDataset rasterXSize=\"9\" rasterYSize=\"9\"><VRTRasterBand dataType=\"Byte\" band=\"1\">'\n"
        "    '<SimpleSource><SourceFilename>' + source + '</SourceFilename></SimpleSource></VRTRasterBand></VRTDataset>')\n"
        "for target in (source, vrt):\n"
        "    try:\n"
        "        with rasterio.open(target) as ds:\n"
        "            ds.read(1)\n"
        "    except Exception:\n"
        "        pass\n"
    )
    clean = {k: v for k, v in os.environ.items() if k not in gate.GDAL_OPTIONS}
    with CountingListener() as plain:  # the listener never answers: without a timeout GDAL would wait forever
        clean_with_timeout = {**clean, "GDAL_HTTP_TIMEOUT": "2", "GDAL_HTTP_MAX_RETRY": "0"}
        subprocess.run([sys.executable, str(script), plain.url, str(tmp_path / "a.vrt")], env=clean_with_timeout, timeout=120, check=True)
        assert plain.count > 0
    with CountingListener() as gated:
        subprocess.run([sys.executable, str(script), gated.url, str(tmp_path / "b.vrt")], env={**clean, **gate.GDAL_OPTIONS}, timeout=120, check=True)
        assert gated.count == 0


def test_header_arithmetic_refuses_before_decoding(tmp_path):
    """A 16384 x 16384 uint16 raster written sparse (a file of a few kB claiming 512 MiB),
    a single 64 MiB strip, and a file cut short: refused from the header."""
    space = RasterSpace.of(tmp_path, limits=RasterLimits(max_pixel_bytes=256 * 2**20, max_block_bytes=32 * 2**20))
    bomb = tmp_path / "bomb.tif"
    with create_raster(bomb, driver="GTiff", width=16384, height=16384, count=1, dtype="uint16", tiled=True, sparse_ok=True, compress="deflate"):
        pass
    assert bomb.stat().st_size < 1_000_000
    e = _refused("too_large", open_raster, bomb, space)
    assert "16384 x 16384" in e.message and str(512 * 2**20) in e.message
    strip = tmp_path / "strip.tif"
    with create_raster(strip, driver="GTiff", width=4096, height=8192, count=1, dtype="uint16", blockysize=8192, sparse_ok=True, compress="deflate"):
        pass
    assert "blocks of" in _refused("too_large", open_raster, strip, space).message
    ok = tmp_path / "ok.tif"
    with create_raster(ok, driver="GTiff", width=300, height=200, count=1, dtype="uint8") as dst:
        dst.write(np.arange(60000, dtype=np.uint8).reshape(1, 200, 300))
    with open_raster(ok, space) as r:
        assert (r.header.width, r.header.height, r.header.pixel_bytes) == (300, 200, 60000)
    cut = tmp_path / "cut.tif"
    cut.write_bytes(ok.read_bytes()[:30000])
    assert "truncated" in _refused("unreadable", open_raster, cut, space).message
    with pytest.raises(RasterRefused):
        open_raster(ok, RasterSpace.of(tmp_path, limits=RasterLimits(max_side_px=100)))


def test_jpeg2000_png_and_jpeg_are_allowed(tmp_path):
    data = (np.arange(64 * 64) % 251).astype(np.uint8).reshape(1, 64, 64)
    for driver, name in (("JP2OpenJPEG", "x.jp2"), ("PNG", "x.png"), ("JPEG", "x.jpg")):
        with create_raster(tmp_path / name, driver=driver, width=64, height=64, count=1, dtype="uint8") as dst:
            dst.write(data)
        with open_raster(tmp_path / name, gate.LOCAL) as r:
            assert r.header.driver == driver and r.dataset.read(1).shape == (64, 64)


def test_a_space_confines_the_opens_inside_it(root):
    """deny_by_default makes a process refuse every open outside a confined block (the
    server's workers); confined admits the job's folders only."""
    space = _alice(root)
    real = space.resolve("a.tif")
    assert gate.current_space() is gate.LOCAL
    _refused("outside_space", open_raster, real, gate.DENIED)
    with gate.confined(space):
        with open_raster(real) as r:
            assert r.header.width == 500
        _refused("outside_space", open_raster, root / "bob" / "secret.tif")
    assert gate.current_space() is gate.LOCAL


def test_every_process_gets_the_network_options():
    """Importing the gate puts its network options in the environment (child processes inherit
    them); a server process locks itself down with all of them (in a child here: the lock-down
    is for the process's life)."""
    for key, value in gate.NETWORK_OPTIONS.items():
        assert os.environ.get(key) == value, key
    code = ("import os; from solver import raster_gate as g; g.lock_down_process(); "
            "assert all(os.environ[k] == v for k, v in g.GDAL_OPTIONS.items()); assert g.current_space() is g.DENIED")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
