"""Take the README's cockpit image from a live demo: ``.venv/bin/python scripts/cockpit_screenshot.py [SECONDS] [OUT]``.

Starts ``bipedtele demo`` (the pilot on the shipped intercontinental trace), opens the
printed cockpit address in Debian's chromium (playwright, from the test extras), waits
SECONDS (62: after the pilot's third pass) and saves the page to OUT (docs/cockpit.png),
then stops the demo.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import tempfile
import time

from playwright.sync_api import sync_playwright


def main(seconds: float, out: str) -> int:
    """Run the demo, save the cockpit after ``seconds`` [s] to ``out``; return the exit code."""
    run = tempfile.mkdtemp(prefix="bipedtele-shot-")
    demo = subprocess.Popen(
        [sys.executable, "-m", "bipedtele.cli", "demo", "--run-dir", run, "--quiet", "--duration", str(seconds + 30)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        assert demo.stdout is not None
        url = None
        deadline = time.monotonic() + 60.0
        while url is None and time.monotonic() < deadline:
            m = re.search(r"(http://127\.0\.0\.1:\d+/\?token=\S+)", demo.stdout.readline())
            url = m.group(1) if m else None
        if url is None:
            sys.stderr.write("cockpit_screenshot: the demo printed no cockpit address\n")
            return 1
        with sync_playwright() as pw:
            browser = pw.chromium.launch(
                executable_path="/usr/bin/chromium", headless=True, args=["--headless", "--no-sandbox", "--disable-gpu"]
            )
            page = browser.new_page(viewport={"width": 1400, "height": 1120})
            for _ in range(120):  # the address is printed before the cockpit serves
                try:
                    page.goto(url)
                    break
                except Exception:  # connection refused until it listens
                    time.sleep(0.5)
            time.sleep(seconds)
            page.screenshot(path=out)
            browser.close()
        return 0
    finally:
        os.killpg(demo.pid, signal.SIGTERM)
        demo.wait(30)


if __name__ == "__main__":
    sys.exit(
        main(
            float(sys.argv[1]) if len(sys.argv) > 1 else 62.0, sys.argv[2] if len(sys.argv) > 2 else "docs/cockpit.png"
        )
    )
