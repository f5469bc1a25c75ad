"""``radar4dgs inspect SCENE``: a scene folder's summary and a contact sheet of its frames."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Optional

import tyro

from radar4dgs.apps.options import default_is


@dataclass
class InspectCommand:
    """Summarise a scene folder and write a contact sheet of frames with radar points coloured by v_r."""

    scene: tyro.conf.Positional[Path]  # scene folder (SCENE_FORMAT.md)
    # contact-sheet PNG to write
    sheet: Annotated[Optional[Path], default_is("SCENE/inspect.png")] = None
    frames: int = 4  # how many frames the contact sheet shows
    json: Path | None = None  # also write the summary as JSON here

    def run(self) -> int:
        from radar4dgs.io.atomic import atomic_write_json
        from radar4dgs.io.preview import contact_sheet, format_summary, save_png, summarize_scene
        from radar4dgs.io.scene import read_scene

        scene = read_scene(self.scene)  # a SceneError is one line (radar4dgs.cli)
        summary = summarize_scene(scene)
        print(format_summary(summary))
        sheet_path = self.sheet or scene.root / "inspect.png"
        save_png(sheet_path, contact_sheet(scene, self.frames))
        print(f"sheet      {sheet_path}")
        if self.json is not None:
            atomic_write_json(self.json, summary)
            print(f"summary    {self.json}")
        sys.stdout.flush()
        return 0
