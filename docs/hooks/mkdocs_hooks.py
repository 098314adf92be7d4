"""mkdocs hooks (``mkdocs.yml`` ``hooks:``): the generated reference pages of the site.

The configuration and command-line pages are written from the code at every build
(``reference_pages``), so they cannot go stale. ``docs/configuration.md`` and ``docs/cli.md`` in
the repository are short stubs saying so (for readers of the sources); the site replaces them.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from reference_pages import cli_page, configuration_page

GENERATED = {"configuration.md": configuration_page, "cli.md": cli_page}


def on_files(files: Any, config: Any) -> Any:
    """Replace ``configuration.md`` and ``cli.md`` by the pages generated from the code."""
    from mkdocs.structure.files import File

    for path, page in GENERATED.items():
        stub = files.get_file_from_path(path)
        if stub is not None:
            files.remove(stub)
        files.append(File.generated(config, path, content=page()))
    return files
