"""scripts/experiments_seed000.py regenerates only its own section of docs/experiments.md."""

from __future__ import annotations

import importlib.util
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[3] / "scripts" / "experiments_seed000.py"


def _load():
    spec = importlib.util.spec_from_file_location("experiments_seed000", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_script_rewrites_only_its_section(tmp_path):
    mod = _load()
    doc = tmp_path / "experiments.md"
    doc.write_text(f"# Experiments\n\nintro\n\n{mod.BEGIN}\nold numbers\n{mod.END}\n\n## Seed 001\nkeep me\n")
    assert mod.main(["--replicates", "1", "--output", str(doc)]) == 0
    text = doc.read_text()
    assert "old numbers" not in text and "keep me" in text and text.startswith("# Experiments\n\nintro")
    assert text.count(mod.BEGIN) == 1 and text.count(mod.END) == 1
    section = text[text.index(mod.BEGIN) : text.index(mod.END)]
    # experiments 1-32, all eight models, both images and both configurations
    for n in (1, 8, 9, 16, 17, 24, 25, 32):
        assert f"| {n} (" in section
    for model in mod.MODELS:
        assert f"({model})" in section
