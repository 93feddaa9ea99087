"""MkDocs hook (mkdocs.yml `hooks:`): the Decisions section lists every docs/decisions/*.md, so a
new decision record is in the site without editing mkdocs.yml."""

from __future__ import annotations

from pathlib import Path


def on_config(config):
    """Fill the nav entry ``Decisions: decisions/`` with the folder's pages, in file-name order."""
    folder = Path(config["docs_dir"]) / "decisions"
    pages = sorted(p.relative_to(config["docs_dir"]).as_posix() for p in folder.glob("*.md"))
    for index, entry in enumerate(config["nav"] or []):
        if isinstance(entry, dict) and entry.get("Decisions") == "decisions/":
            config["nav"][index] = {"Decisions": pages}
    return config
