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
//
// The accessibility audit is axe-core (npm), run in the page three
// times: on a new device's page (the first password's form alone), on the
// whole page with a refused setting marked, and at a phone's width. axe's source goes in through
// playwright's page.evaluate, which the page's Content-Security-Policy does
// not apply to (a script tag would be refused: only the page's own script,
// by its hash, runs); the alternative, a context with bypassCSP, would turn
// the policy off for the whole run, and the run checks the page as it is
// served. Every violation is written to axe.json in the artifacts; a
// serious or critical one fails the run.
'use strict';

const fs = require('fs');
const net = require('net');
const path = require('path');
const { chromium } = require('playwright-core');

const AXE = fs.readFileSync(require.resolve('axe-core/axe.min.js'), 'utf8');

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

// The audit of the page as it is now: every violation, by rule, impact
// and the elements it found.
async function audit(page, name, audits) {
  await page.evaluate(AXE);
  const result = await page.evaluate(() => axe.run(document, { resultTypes: ['violations'] }));
  const violations = result.violations.map((v) => ({ id: v.id, impact: v.impact, help: v.help, nodes: v.nodes.map((n) => n.target.join(' ')) }));
  audits[name] = { passes: result.passes.length, violations };
  const severe = violations.filter((v) => v.impact == 'serious' || v.impact == 'critical');
  check(severe.length == 0, `accessibility (${name}): ${JSON.stringify(severe)}`);
}

// The telemetry tables' cells as text, read at once.
async function telemetry(page) {
  return page.evaluate(() => [...document.querySelectorAll('#joints td, #task td')].map((td) => td.textContent));
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
  await shows(page, '#device', '02:4d:42:53:49:4d');
  await shows(page, '#device', '198.18.0.2/24');
  // The page says whether its connection is encrypted.
  summary.connection = url.startsWith('https:') ? 'HTTPS, encrypted' : 'plain HTTP: NOT ENCRYPTED';
  await shows(page, '#device', 'Connection' + summary.connection);
  // The CPU load hal-sim's executor loop measures, once its first second has passed.
  await shows(page, '#device', /CPU load\d{1,3} %/);
  await shows(page, '#robot-state', 'STANDBY (1)');
  await shows(page, '#robot', 'simulated robot');
  await shows(page, '#counters', 'requests');
  check((await page.textContent('h1')) == 'mbio-53494d', 'the device name is the page\'s heading');
  check(await page.isVisible('#first-password'), 'the warning that no admin password is set');
  // A new device takes nothing but its first password: no other control until then.
  for (const id of ['settings', 'locate', 'reboot', 'factory-reset', 'password', 'update-file']) {
    check(!(await page.isVisible('#' + id)), `#${id} waits for the first password`);
  }
  await shows(page, '#claim', 'within 10 minutes of power-up');
  summary.audits = {};
  await audit(page, 'new device', summary.audits);
  await page.getByLabel('New admin password').fill(PASSWORD);
  await page.click('text=Set password');
  await page.waitForSelector('#first-password', { state: 'hidden', timeout: 3000 });
  await page.waitForSelector('#settings', { state: 'visible', timeout: 3000 });
  check(await page.isVisible('#locate'), 'the controls once the password is set');

  // What the test's Modbus master wrote, and that it is listed.
  await shows(page, '#connections', '198.18.0.1');
  for (const id of ['do-1', 'do-4', 'do-16', 'tool-do-1', 'tool-do-3']) await page.waitForSelector(`#${id}.on`, { timeout: 2000 });
  check(!(await page.isVisible('#do-2.on')), 'DO2 is off');
  // The lamps say it in text too, not in colour alone.
  await shows(page, '#do-text', 'DO: 1, 4, 16 on');
  await shows(page, '#tool-di-text', 'Tool DI: all off');
  await shows(page, '#analog', '8.000 mA');
  await shows(page, '#analog', '5.000 V');

  // Lamps follow inputs set on the control socket within 1 s.
  summary.lamp_ms = [];
  summary.lamp_ms.push(await lampFollows(page, 'di-3', 'set di 3 1', true));
  summary.lamp_ms.push(await lampFollows(page, 'di-3', 'set di 3 0', false));
  summary.lamp_ms.push(await lampFollows(page, 'tool-di-2', 'set tool-di 2 1', true));
  await sendOk('set di 1 1');
  await sendOk('set di 12 1');
  await shows(page, '#di-text', 'DI: 1, 12 on', LAMP_MS);
  await sendOk('set ai 1 12345');
  await shows(page, '#analog', '12.345 mA', LAMP_MS);

  // The robot's telemetry, each value with its unit, as the API has it:
  // the idle arm's 120 mm tool, then the arm moving.
  await shows(page, '#task', '120.0 mm');
  const api = await (await fetch(new URL('/api/telemetry', url))).json();
  const still = await telemetry(page);
  summary.telemetry_cells = still.length;
  check(still.length == 5 * 6 + 4 * 6, `every point has a cell: ${still.length}`);
  check(still[0] == api.joint_position_deg[0].toFixed(1) + ' °', `joint 1's position as the API has it: ${still[0]} and ${api.joint_position_deg[0]}`);
  for (const [i, unit] of [[0, ' °'], [6, ' °/s'], [12, ' mA'], [18, ' °C'], [24, ' N·m'], [30, ' mm'], [33, ' °'], [36, ' mm/s'], [39, ' °/s'], [48, ' N'], [51, ' N·m']]) {
    check(still[i].endsWith(unit) && !isNaN(parseFloat(still[i])), `cell ${i} is a number in${unit}: ${JSON.stringify(still[i])}`);
  }
  await sendOk('robot state operating');
  await shows(page, '#robot-state', 'OPERATING (2)', LAMP_MS);
  await page.waitForTimeout(1500);
  const moving = await telemetry(page);
  summary.telemetry_moved = moving.filter((v, i) => v != still[i]).length;
  check(moving.slice(0, 6).some((v, i) => v != still[i]), `the joints move live: ${still.slice(0, 6)} then ${moving.slice(0, 6)}`);
  summary.telemetry_example = moving.slice(0, 6);

  // The robot's state is announced (a live region), its flags said in
  // words; so are the connection and every message.
  check((await page.getAttribute('#robot-state', 'aria-live')) == 'polite', 'the robot state is a live region');
  for (const id of ['live', 'action-message', 'settings-message', 'password-message', 'update-message']) {
    check((await page.getAttribute('#' + id, 'role')) == 'status', `#${id} is announced`);
  }
  await sendOk('robot estop press');
  await shows(page, '#robot-state', 'EMERGENCY STOP (6)', LAMP_MS);
  await shows(page, '#robot .alarm', 'on', LAMP_MS);
  // Positions and velocities (the temperatures go on cooling), once a
  // poll has brought a sample taken after the stop (every 100 ms).
  await page.waitForTimeout(700);
  const halted = (await telemetry(page)).slice(0, 12);
  await page.waitForTimeout(1000);
  check(JSON.stringify((await telemetry(page)).slice(0, 12)) == JSON.stringify(halted), 'an emergency stop halts the arm');
  await sendOk('robot estop release');
  await sendOk('robot reset');
  await shows(page, '#robot-state', 'STANDBY (1)', LAMP_MS);

  // Focus stays where the person put it while the page refreshes.
  const port = page.getByLabel('port', { exact: true });
  await port.focus();
  await port.fill('1502');
  await page.waitForTimeout(1500);
  summary.focus_kept = await page.evaluate(() => document.activeElement.id);
  check(summary.focus_kept == 'modbus-port', `focus after three refreshes: ${summary.focus_kept}`);
  check((await port.inputValue()) == '1502', 'what was typed stays');
  await port.fill('502');

  // Typed controls: choices, numbers with their ranges.
  check((await page.locator('#network-mode option').allTextContents()).join() == 'dhcp,static', 'network.mode is a choice');
  check((await page.locator('#modbus-write-policy option').allTextContents()).join() == 'seed,strict', 'write_policy is a choice');
  check((await page.getAttribute('#modbus-port', 'type')) == 'number' && (await page.getAttribute('#modbus-port', 'max')) == '65535', 'the port is a number');
  await shows(page, '#robot-poll-ms-hint', '20 to 1000 ms');

  // A bad setting: its error beside its field, tied to it, and nothing changed.
  const before = await settings();
  const unitId = page.getByLabel('unit id');
  await unitId.fill('300');
  await page.click('#save');
  const error = page.locator('#modbus-unit-id-error');
  await shows(page, '#modbus-unit-id-error', 'any, or 1-247');
  summary.field_error = await error.textContent();
  check((await unitId.getAttribute('aria-invalid')) == 'true', 'the refused field is marked');
  check((await unitId.getAttribute('aria-describedby')).split(' ').includes('modbus-unit-id-error'), 'the error describes its field');
  check(await page.evaluate(() => document.activeElement.id) == 'modbus-unit-id', 'the refused field has the focus');
  await shows(page, '#settings-message', 'Not saved');
  check(JSON.stringify(await settings()) == JSON.stringify(before), 'a refused change changes nothing');
  await audit(page, 'whole page, a field refused', summary.audits);
  await page.screenshot({ path: path.join(artifacts, 'page-error.png'), fullPage: true });

  // A good one applies.
  await unitId.fill('7');
  await page.click('#save');
  await shows(page, '#settings-message', 'Saved and applied');
  check((await error.textContent()) == '', 'the error is gone');
  check((await unitId.getAttribute('aria-invalid')) != 'true', 'the field is no longer marked');
  summary.unit_id = (await settings()).modbus.unit_id;
  check(summary.unit_id == '7', `unit_id is ${summary.unit_id}`);
  check((await unitId.inputValue()) == '7', 'the form shows the saved value');

  // The output masks as boxes: DO 3 and 16, tool DO 2 in the safe state.
  const safeDo = page.locator('#fields fieldset[data-key="watchdog.safe_do"] input[type=checkbox]');
  const safeToolDo = page.locator('#fields fieldset[data-key="watchdog.safe_tool_do"] input[type=checkbox]');
  check((await safeDo.count()) == 16 && (await safeToolDo.count()) == 6, 'a box per output');
  await safeDo.nth(2).check();
  await safeDo.nth(15).check();
  await safeToolDo.nth(1).check();
  // An allow-list as a list, one network a line: one that is not a
  // network is refused, and the error is tied to the list.
  const allow = page.getByLabel('allow connect');
  check((await allow.inputValue()) == 'any', 'the list as the device has it');
  await allow.fill('198.18.0.0/15\n198.18.0.0/33');
  await page.click('#save');
  await shows(page, '#modbus-allow-connect-error', 'up to 8 comma-separated networks', 3000);
  check((await allow.getAttribute('aria-invalid')) == 'true', 'the refused list is marked');
  check((await allow.getAttribute('aria-describedby')).split(' ').includes('modbus-allow-connect-error'), 'the error describes the list');
  summary.list_error = await page.textContent('#modbus-allow-connect-error');
  check((await settings()).watchdog.safe_do == 0, 'a refused change saves no box either');
  await allow.fill('198.18.0.0/15\n\n 10.0.0.9 ');
  await page.click('#save');
  await shows(page, '#settings-message', 'Saved and applied');
  const saved = await settings();
  summary.masks = [saved.watchdog.safe_do, saved.watchdog.safe_tool_do];
  check(saved.watchdog.safe_do == (1 << 2 | 1 << 15) && saved.watchdog.safe_tool_do == 2, `the masks saved: ${summary.masks}`);
  summary.allow_connect = saved.modbus.allow_connect;
  check(saved.modbus.allow_connect == '198.18.0.0/15,10.0.0.9/32', `the list saved: ${saved.modbus.allow_connect}`);
  check((await allow.inputValue()) == '198.18.0.0/15\n10.0.0.9/32', 'the form shows the saved list, a network a line');
  check(await safeDo.nth(15).isChecked() && !(await safeDo.nth(14).isChecked()), 'the form shows the saved mask');

  // Locate sets hal-sim's flag; factory reset asks first.
  await page.click('#locate');
  await shows(page, '#action-message', 'blinks for 10 s');
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
  const password = page.getByLabel('Admin password, for changes');
  await password.fill('');
  await page.click('#locate');
  await shows(page, '#action-message', '401: the admin password is required');
  summary.refused = await page.textContent('#action-message');
  await password.fill(PASSWORD);
  await page.click('#locate');
  await shows(page, '#action-message', 'blinks for 10 s');
  await password.fill('wrong-horse');
  await unitId.fill('9');
  await page.click('#save');
  await shows(page, '#settings-message', '401', 4000);
  check((await settings()).modbus.unit_id == '7', 'a change with a wrong password changes nothing');
  await password.fill(PASSWORD);
  await unitId.fill('7');
  await page.click('#save');
  await shows(page, '#settings-message', 'Nothing changed');

  await page.screenshot({ path: path.join(artifacts, 'page.png'), fullPage: true });
  // And on a phone's width, audited again (the layout changes).
  await page.setViewportSize({ width: 400, height: 900 });
  await audit(page, 'phone width', summary.audits);
  await page.screenshot({ path: path.join(artifacts, 'page-narrow.png'), fullPage: true });
  fs.writeFileSync(path.join(artifacts, 'axe.json'), JSON.stringify(summary.audits, null, 2));
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
