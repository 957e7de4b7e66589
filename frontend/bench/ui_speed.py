"""Speed of the browser UI on a large survey: recognise, hash and upload N photos in headless Chromium
against the real platform (API + SQLite on this machine), printing the figures.

    .venv/bin/python frontend/bench/ui_speed.py [--images 200] [--mb 4]

Photos are the simulator's JPEG heads padded with random bytes to the requested size (recognition reads
the first 64 kB; hashing and upload read everything)."""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tests.frontend import e2e_platform  # noqa: E402
from tests.frontend.ui_helpers import login  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=200)
    ap.add_argument("--mb", type=float, default=4.0, help="size of each photo (MB)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="georef-ui-bench-") as tmp:
        tmp = Path(tmp)
        site = e2e_platform.simulate_small(tmp / "site")
        head = (site / "images" / "IMG_0001.JPG").read_bytes()
        size = int(args.mb * 1e6)
        photos = []
        (tmp / "photos").mkdir()
        for i in range(args.images):
            p = tmp / "photos" / f"DJI_{i:04d}.JPG"
            p.write_bytes(head + os.urandom(max(0, size - len(head))))
            photos.append(str(p))
        total_mb = sum(Path(p).stat().st_size for p in photos) / 1e6
        plat = e2e_platform.start(tmp / "platform", worker=False)
        try:
            from playwright.sync_api import sync_playwright

            with sync_playwright() as pw:
                b = pw.chromium.launch(executable_path="/usr/bin/chromium", args=["--no-sandbox"])
                page = b.new_page(base_url=plat.url, viewport={"width": 1366, "height": 900})
                page.set_default_timeout(600_000)
                login(page)
                page.get_by_role("link", name=e2e_platform.DEMO_SITE).click()
                page.get_by_role("button", name="New survey").click()
                page.get_by_role("button", name="Create and upload data").click()
                page.get_by_text("Drop the flight's folder here").wait_for()
                t0 = time.perf_counter()
                page.locator("input[data-testid=file-input]").set_input_files(photos)
                page.locator(".group-images").wait_for()
                t_sniff = time.perf_counter() - t0
                t1 = time.perf_counter()
                page.get_by_role("button", name="Upload").first.click()
                page.get_by_text("all files uploaded").wait_for()
                t_up = time.perf_counter() - t1
                b.close()
        finally:
            e2e_platform.stop(plat)
    print(f"{args.images} photos, {total_mb:.0f} MB")
    print(f"recognised and listed in {t_sniff:.2f} s ({1000 * t_sniff / args.images:.1f} ms per photo, includes "
          "handing the files to the page)")
    print(f"hashed (SHA-256) and uploaded to the local API in {t_up:.1f} s: {total_mb / t_up:.0f} MB/s overall")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
