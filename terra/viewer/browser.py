"""Headless Chromium for the viewer: open its page, act on its controls, take screenshots.

Uses Debian's `chromium` and `chromium-driver` (scripts/setup-test-browser.sh installs them)
through selenium, with a fresh profile and no background networking (the machine has no network
beyond package registries). WebGL runs in software (SwiftShader). For tests and documentation
screenshots; `terra view` itself needs no browser here.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

HEADLESS_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
)


def browser_missing() -> str | None:
    """Why no headless browser can run here (None when one can)."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install selenium; it is in the test extra)"
    for program in ("chromium", "chromedriver"):
        if shutil.which(program) is None:
            return (
                f"{program} is not installed (scripts/setup-test-browser.sh installs Debian's chromium and its driver)"
            )
    return None


class HeadlessPage:
    """One headless Chromium window of `size` pixels showing `url`."""

    def __init__(self, url: str, size: tuple[int, int] = (1400, 900)):
        from selenium import webdriver
        from selenium.webdriver.chrome.options import Options
        from selenium.webdriver.chrome.service import Service

        self._profile = tempfile.mkdtemp(prefix="terra-chromium-")
        options = Options()
        options.binary_location = shutil.which("chromium") or "/usr/bin/chromium"
        for flag in (*HEADLESS_FLAGS, f"--user-data-dir={self._profile}", f"--window-size={size[0]},{size[1]}"):
            options.add_argument(flag)
        self.driver = webdriver.Chrome(
            service=Service(shutil.which("chromedriver") or "/usr/bin/chromedriver"), options=options
        )
        self.driver.get(url)

    def text(self) -> str:
        return str(self.driver.execute_script("return document.body ? document.body.innerText : ''"))

    def wait_for_text(self, needle: str, timeout: float = 60.0) -> str:
        """The page's text once it contains `needle` (TimeoutError after `timeout` seconds)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            text = self.text()
            if needle in text:
                return text
            time.sleep(0.25)
        raise TimeoutError(f"the page did not show {needle!r} within {timeout:g} s")

    def field(self, label: str):
        """The input next to the GUI label `label`."""
        from selenium.webdriver.common.by import By

        return self.driver.find_element(By.XPATH, f"//*[normalize-space(text())='{label}']/following::input[1]")

    def type_into(self, label: str, text: str) -> None:
        element = self.field(label)
        element.clear()
        element.send_keys(text)

    def click(self, button_text: str) -> None:
        from selenium.webdriver.common.by import By

        self.driver.find_element(By.XPATH, f"//button[normalize-space()='{button_text}']").click()

    def dismiss_notifications(self) -> None:
        """Close toasts (e.g. viser's note that WebGL runs in software)."""
        self.driver.execute_script(
            "document.querySelectorAll('.mantine-Notification-closeButton, [class*=Notification] button')"
            ".forEach(b => b.click());"
        )

    def screenshot(self, path: str | Path) -> Path:
        path = Path(path)
        self.driver.save_screenshot(str(path))
        return path

    def close(self) -> None:
        try:
            self.driver.quit()
        finally:
            shutil.rmtree(self._profile, ignore_errors=True)
