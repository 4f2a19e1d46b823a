// The device's page in a real browser: Debian's chromium, driven by
// playwright-core, against hal-sim. tests/tests/hal_sim_page.rs starts
// hal-sim in a network namespace and runs this script inside it:
//
//   node page.js URL CONTROL_SOCKET ARTIFACT_DIR FIRMWARE_VERSION
//
// Each step checks what a person would see; the first that fails ends the
// run with its reason on stderr, a screenshot (page-failure.png) and exit
// status 1. At the end it prints one line of JSON: what it measured, which
// the Rust test checks again.
'use strict';

const net = require('net');
const path = require('path');
const { chromium } = require('playwright-core');

const [url, control, artifacts, version] = process.argv.slice(2);
if (!version) {
  console.error('usage: node page.js URL CONTROL_SOCKET ARTIFACT_DIR FIRMWARE_VERSION');
  process.exit(2);
}

const CHROMIUM = '/usr/bin/chromium';
// How long a lamp may take to follow an input (the page polls every 500 ms).
const LAMP_MS = 1000;
const PASSWORD = 'correct-horse';

class Failed extends Error {}
function check(ok, what) {
  if (!ok) throw new Failed(what);
}

// One command on hal-sim's control socket: its reply line.
function send(command) {
  return new Promise((resolve, reject) => {
    const socket = net.createConnection(control);
    let reply = '';
    socket.setTimeout(5000, () => socket.destroy(new Error(`no reply to ${command}`)));
    socket.on('connect', () => socket.write(command + '\n'));
    socket.on('data', (data) => {
      reply += data;
      if (reply.includes('\n')) {
        socket.end();
        resolve(reply.trim());
      }
    });
    socket.on('error', reject);
  });
}

async function sendOk(command) {
  const reply = await send(command);
  check(reply.startsWith('ok'), `${command}: ${reply}`);
  return reply.slice(2).trim();
}

// The API seen from outside the page (node's fetch, in the same namespace).
async function settings() {
  const response = await fetch(new URL('/api/settings', url));
  check(response.status == 200, `GET /api/settings: ${response.status}`);
  return response.json();
}

// Waits until `selector` shows `text` (a substring), within `ms`.
async function shows(page, selector, text, ms = 3000) {
  try {
    await page.locator(selector).filter({ hasText: text }).first().waitFor({ timeout: ms });
  } catch (e) {
    const now = await page.locator(selector).first().textContent().catch(() => '(none)');
    throw new Failed(`${selector} does not show ${typeof text === "string" ? JSON.stringify(text) : String(text)} within ${ms} ms: ${JSON.stringify(now)}`);
  }
}

// Sets an input through the control socket and measures how long the lamp
// takes to follow it.
async function lampFollows(page, id, command, on) {
  await sendOk(command);
  const start = Date.now();
  const selector = on ? `#${id}.on` : `#${id}:not(.on)`;
  try {
    await page.waitForSelector(selector, { timeout: LAMP_MS });
  } catch (e) {
    throw new Failed(`lamp ${id} did not turn ${on ? 'on' : 'off'} within ${LAMP_MS} ms of "${command}"`);
  }
  return Date.now() - start;
}

async function main(browser) {
  const summary = {};
  const page = await browser.newPage({ viewport: { width: 1280, height: 900 } });
  const errors = [];
  page.on('pageerror', (error) => errors.push(error.message));
  // Everything the page loads: only the device's own address.
  const requests = [];
  page.on('request', (request) => requests.push(request.url()));

  // Loads, and the first poll comes back.
  const response = await page.goto(url);
  check(response.status() == 200, `GET /: ${response.status()}`);
  check((await response.headerValue('content-encoding')) == 'gzip', 'the page comes gzipped');
  await page.waitForSelector('#live.ok', { timeout: 5000 });
  summary.title = await page.title();
  check(summary.title.includes('mbio-53494d') && summary.title.includes('Modbus I/O adapter'), `title: ${summary.title}`);
  summary.model = await page.textContent('#model');
  check(summary.model.includes(`firmware ${version}`), `the version is shown: ${summary.model}`);
  await shows(page, '#dev', '02:4d:42:53:49:4d');
  await shows(page, '#dev', '198.18.0.2/24');
  // The CPU load hal-sim's executor loop measures, once its first second has passed.
  await shows(page, '#dev', /CPU load\d{1,3} %/);
  await shows(page, '#state', 'STANDBY (1)');
  await shows(page, '#rob', 'simulated robot');
  await shows(page, '#cnt', 'requests');
  check(await page.isVisible('#warn'), 'the warning that no admin password is set');
  // A new device takes nothing but its first password: no other control until then.
  for (const id of ['set', 'loc', 'rbt', 'fac', 'pw', 'ff']) check(!(await page.isVisible('#' + id)), `#${id} waits for the first password`);
  await shows(page, '#claim', 'within 10 minutes of power-up');
  await page.fill('#np', PASSWORD);
  await page.click('text=Set password');
  await page.waitForSelector('#warn', { state: 'hidden', timeout: 3000 });
  await page.waitForSelector('#set', { state: 'visible', timeout: 3000 });
  check(await page.isVisible('#loc'), 'the controls once the password is set');

  // What the test's Modbus master wrote, and that it is listed.
  await shows(page, '#con', '198.18.0.1');
  for (const id of ['do1', 'do4', 'do16', 'tdo1', 'tdo3']) await page.waitForSelector(`#${id}.on`, { timeout: 2000 });
  check(!(await page.isVisible('#do2.on')), 'DO2 is off');
  await shows(page, '#an', '8.000 mA');
  await shows(page, '#an', '5.000 V');

  // Lamps follow inputs set on the control socket within 1 s.
  summary.lamp_ms = [];
  summary.lamp_ms.push(await lampFollows(page, 'di3', 'set di 3 1', true));
  summary.lamp_ms.push(await lampFollows(page, 'di3', 'set di 3 0', false));
  summary.lamp_ms.push(await lampFollows(page, 'tdi2', 'set tool-di 2 1', true));
  await sendOk('set di 1 1');
  await sendOk('set di 12 1');
  await sendOk('set ai 1 12345');
  await shows(page, '#an', '12.345 mA', LAMP_MS);
  await sendOk('robot estop press');
  await shows(page, '#state', 'EMERGENCY STOP (6)', LAMP_MS);
  await page.waitForSelector('#flags i.r', { timeout: LAMP_MS });
  await sendOk('robot estop release');
  await sendOk('robot reset');
  await shows(page, '#state', 'STANDBY (1)', LAMP_MS);

  // A bad setting: its error beside its field, and nothing changed.
  const before = await settings();
  const unitId = page.locator('input[name="modbus.unit_id"]');
  await unitId.fill('300');
  await page.click('#save');
  const error = page.locator('input[name="modbus.unit_id"] + small');
  await shows(page, 'input[name="modbus.unit_id"] + small', 'any, or 1-247');
  summary.field_error = await error.textContent();
  check((await unitId.getAttribute('class')) == 'bad', 'the refused field is marked');
  await shows(page, '#smsg', 'Not saved');
  check(JSON.stringify(await settings()) == JSON.stringify(before), 'a refused change changes nothing');
  await page.screenshot({ path: path.join(artifacts, 'page-error.png'), fullPage: true });

  // A good one applies.
  await unitId.fill('7');
  await page.click('#save');
  await shows(page, '#smsg', 'Saved and applied');
  check((await error.textContent()) == '', 'the error is gone');
  summary.unit_id = (await settings()).modbus.unit_id;
  check(summary.unit_id == '7', `unit_id is ${summary.unit_id}`);
  check((await unitId.inputValue()) == '7', 'the form shows the saved value');

  // Locate sets hal-sim's flag; factory reset asks first.
  await page.click('#loc');
  await shows(page, '#amsg', 'blinks for 10 s');
  summary.locate = await sendOk('get locate');
  check(summary.locate == '1', `get locate: ${summary.locate}`);
  let asked = '';
  page.once('dialog', (dialog) => {
    asked = dialog.message();
    dialog.dismiss();
  });
  await page.click('text=Factory reset');
  check(asked.includes('Erase every setting'), `factory reset asks first: ${JSON.stringify(asked)}`);

  // A change without the password is refused visibly (401), and with it
  // goes through.
  await page.fill('#pw', '');
  await page.click('#loc');
  await shows(page, '#amsg', '401: the admin password is required');
  summary.refused = await page.textContent('#amsg');
  await page.fill('#pw', PASSWORD);
  await page.click('#loc');
  await shows(page, '#amsg', 'blinks for 10 s');
  await page.fill('#pw', 'wrong-horse');
  await unitId.fill('9');
  await page.click('#save');
  await shows(page, '#smsg', '401', 4000);
  check((await settings()).modbus.unit_id == '7', 'a change with a wrong password changes nothing');
  await page.fill('#pw', PASSWORD);
  await unitId.fill('7');
  await page.click('#save');
  await shows(page, '#smsg', 'Nothing changed');

  await page.screenshot({ path: path.join(artifacts, 'page.png'), fullPage: true });
  // And on a phone's width.
  await page.setViewportSize({ width: 400, height: 900 });
  await page.screenshot({ path: path.join(artifacts, 'page-narrow.png'), fullPage: true });
  summary.page_errors = errors;
  check(errors.length == 0, `errors in the page: ${errors.join('; ')}`);
  const origin = new URL(url).origin;
  const elsewhere = requests.filter((r) => !r.startsWith(origin + '/') && !r.startsWith('data:'));
  check(elsewhere.length == 0, `requests elsewhere: ${elsewhere.join(' ')}`);
  summary.requests = requests.length;
  return summary;
}

(async () => {
  const browser = await chromium.launch({
    executablePath: CHROMIUM,
    args: ['--headless', '--no-sandbox', '--disable-background-networking'],
  });
  let status = 0;
  try {
    console.log(JSON.stringify(await main(browser)));
  } catch (e) {
    console.error(e instanceof Failed ? `page: ${e.message}` : e);
    for (const page of browser.contexts().flatMap((c) => c.pages())) {
      await page.screenshot({ path: path.join(artifacts, 'page-failure.png'), fullPage: true }).catch(() => {});
    }
    status = 1;
  } finally {
    await browser.close();
  }
  process.exit(status);
})();
