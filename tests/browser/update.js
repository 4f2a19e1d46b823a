// The page's firmware update in a real browser: Debian's chromium, driven
// by playwright-core, against the mps2-an386 image with `update` in QEMU.
// tests/tests/qemu_page_update.rs boots it and runs this script:
//
//   node update.js URL ARTIFACT_DIR GOOD_FILE OLD_VERSION NEW_VERSION [REFUSED_FILE=WORD ...]
//
// Each refused file is refused and the page says why (its message holds
// WORD, and the running version stays); the good one is sent
// with its progress shown, taken, and after the device's restart the page
// shows the new version running and the old one as the previous. The
// browser's upload is throttled (DevTools' network emulation) so that the
// progress has moments to be seen. The first failed step ends the run
// with its reason on stderr, a screenshot (update-failure.png) and exit
// status 1; at the end one line of JSON says what was seen.
'use strict';

const path = require('path');
const { chromium } = require('playwright-core');

const [url, artifacts, good, oldVersion, newVersion, ...refusals] = process.argv.slice(2);
if (!newVersion || !refusals.every((r) => r.includes('='))) {
  console.error('usage: node update.js URL ARTIFACT_DIR GOOD_FILE OLD_VERSION NEW_VERSION [REFUSED_FILE=WORD ...]');
  process.exit(2);
}

const CHROMIUM = '/usr/bin/chromium';
// Upload bytes per second in the browser: a 170 KB file takes about 3 s.
const UPLOAD_RATE = 64 * 1024;
// The device's restart: reboot, swap, network, first poll.
const RESTART_MS = 60000;
// The first admin password, set from the page: a new device takes no
// update (no change at all) before it.
const PASSWORD = 'correct-horse';

class Failed extends Error {}
function check(ok, what) {
  if (!ok) throw new Failed(what);
}

// The "Firmware" list as {term: value}, read in one evaluation: the page
// rewrites the list at each status poll, and `$$eval` queries the elements
// first and reads them in a second step, by when a poll may have detached
// them (a dt with no sibling).
async function firmware(page) {
  return page.evaluate(() => Object.fromEntries([...document.querySelectorAll('#firmware dt')]
    .map((dt) => [dt.textContent, dt.nextElementSibling.textContent])));
}

// Uploads `file` through the page; samples the progress bar until the
// page has the device's answer. The answer and the bar's values seen.
async function upload(page, file) {
  await page.setInputFiles('#update-file', file);
  await page.click('#update-start');
  const seen = [];
  const deadline = Date.now() + 120000;
  for (;;) {
    const [value, message, busy] = await page.evaluate(() => [
      document.getElementById('update-progress').value,
      document.getElementById('update-message').textContent,
      document.getElementById('update-start').disabled,
    ]);
    if (seen[seen.length - 1] !== value) seen.push(value);
    if (!busy) return { message, seen };
    check(Date.now() < deadline, `no answer to the upload of ${file}: ${message}`);
    await page.waitForTimeout(25);
  }
}

async function main() {
  const browser = await chromium.launch({
    executablePath: CHROMIUM,
    args: ['--headless', '--no-sandbox', '--disable-background-networking'],
  });
  const page = await browser.newPage({ viewport: { width: 1280, height: 900 } });
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  const summary = {};
  try {
    const cdp = await page.context().newCDPSession(page);
    await cdp.send('Network.enable');
    await cdp.send('Network.emulateNetworkConditions', {
      offline: false, latency: 0, downloadThroughput: -1, uploadThroughput: UPLOAD_RATE,
    });
    await page.goto(url);
    await page.waitForSelector('#first-password:not([hidden])', { timeout: 15000 });
    check(!(await page.isVisible('#update-file')), 'no upload before the first password');
    await page.fill('#new-password', PASSWORD);
    await page.click('text=Set password');
    await page.waitForSelector('#first-password', { state: 'hidden', timeout: 5000 });
    await page.waitForSelector('#update:not([hidden])', { timeout: 15000 });
    await page.waitForSelector('#update-file', { state: 'visible', timeout: 5000 });
    await page.waitForFunction(() => document.querySelectorAll('#firmware dt').length > 0);
    summary.before = await firmware(page);
    check(summary.before.Running.startsWith(oldVersion), `running before: ${JSON.stringify(summary.before)}`);

    summary.refused = [];
    for (const refusal of refusals) {
      const split = refusal.lastIndexOf('=');
      const [file, word] = [refusal.slice(0, split), refusal.slice(split + 1)];
      const refused = await upload(page, file);
      summary.refused.push(refused.message);
      check(refused.message.startsWith('Not updated') && refused.message.includes(word),
        `${path.basename(file)}: "${refused.message}" does not say "${word}"`);
      const now = await firmware(page);
      check(now.Running.startsWith(oldVersion), `running after ${path.basename(file)}: ${JSON.stringify(now)}`);
    }

    const taken = await upload(page, good);
    summary.good = taken.message;
    summary.progress = taken.seen;
    check(taken.message.includes(`Version ${newVersion} taken`), `the good file: ${taken.message}`);
    const between = taken.seen.filter((v) => v > 0 && v < 1);
    check(between.length >= 2, `the progress bar moved in steps: ${JSON.stringify(taken.seen)}`);
    check(taken.seen.every((v, i) => i == 0 || v >= taken.seen[i - 1]), `the progress never went back: ${taken.seen}`);

    // The device restarts into the new version; the page follows it.
    await page.waitForFunction((v) => {
      const dd = [...document.querySelectorAll('#firmware dt')].find((dt) => dt.textContent == 'Running');
      return dd && dd.nextElementSibling.textContent.startsWith(v);
    }, newVersion, { timeout: RESTART_MS, polling: 250 });
    await page.waitForFunction(() => document.getElementById('live').className == 'ok');
    summary.after = await firmware(page);
    check(summary.after.Previous == oldVersion, `the previous version after: ${JSON.stringify(summary.after)}`);
    await page.screenshot({ path: path.join(artifacts, 'update.png'), fullPage: true });
    summary.page_errors = errors;
    console.log(JSON.stringify(summary));
  } catch (e) {
    await page.screenshot({ path: path.join(artifacts, 'update-failure.png'), fullPage: true }).catch(() => {});
    console.error(e instanceof Failed ? `failed: ${e.message}` : e);
    console.error(`seen so far: ${JSON.stringify(summary)}; page errors: ${JSON.stringify(errors)}`);
    process.exitCode = 1;
  } finally {
    await browser.close();
  }
}

main();
