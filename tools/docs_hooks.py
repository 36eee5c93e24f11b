"""MkDocs hook (mkdocs.yml `hooks:`): fills the generated parts of the pages from the results files.

A page marks a generated block with ``<!-- generated: NAME -->`` (NAME one of docs_site.BLOCKS) and an
inline value with ``[[scenario.metric:format]]`` (from benchmarks/results/scenarios.json).
"""

from __future__ import annotations

import sys
from pathlib import Path

TOOLS = Path(__file__).resolve().parent
if str(TOOLS) not in sys.path:
    sys.path.insert(0, str(TOOLS))

import docs_site  # noqa: E402  (tools/docs_site.py)


def on_page_markdown(markdown, page, config, files):  # noqa: ARG001 (the MkDocs hook signature)
    return docs_site.render(markdown)


def on_files(files, config):
    """Serve the benchmark figures (benchmarks/results/*.png) as results/NAME.png for the generated pages."""
    from mkdocs.structure.files import File

    for png in docs_site.result_images():
        files.append(File.generated(config, f"results/{png.relative_to(docs_site.RESULTS).as_posix()}",
                                    abs_src_path=str(png)))
    return files


def on_page_content(html, page, config, files):  # noqa: ARG001 (the MkDocs hook signature)
    """The docstrings' Sphinx roles (``:class:`~a.B` ``) as plain code: drop the role and the ``~``."""
    return docs_site.plain_roles(html)
