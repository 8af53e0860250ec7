// What every browser test shares: the server under test from the environment, the artifacts folder,
// and headless Chromium with a fresh profile (WebGL through SwiftShader: there is no GPU here).
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh sets them); CHROMIUM (default /usr/bin/chromium).
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import {fileURLToPath} from 'node:url';
import {chromium} from 'playwright-core';

export const ARTIFACTS = path.join(path.dirname(fileURLToPath(import.meta.url)), 'artifacts');
export const WAIT = {timeout: 20000};  // bound on a hung page, not a speed assertion
export const tid = (id) => `[data-testid="${id}"]`;
export const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
export const CHROMIUM_ARGS = ['--headless=new', '--no-sandbox', '--disable-gpu', '--disable-background-networking',
                              '--disable-component-update', '--no-first-run', '--disable-sync', '--disable-quic',
                              '--use-angle=swiftshader', '--enable-unsafe-swiftshader'];

// The server the test drives: {BASE_URL, TOKEN} from the environment, or a sentence saying what to set.
export function serverUnderTest(urlVariable = 'TENDRIL_URL', tokenVariable = 'TENDRIL_TOKEN') {
  const BASE_URL = (process.env[urlVariable] || '').replace(/\/$/, '');
  const TOKEN = process.env[tokenVariable] || '';
  if (!BASE_URL || !TOKEN) throw new Error(`Set ${urlVariable} and ${tokenVariable}, or run tests/e2e/run.sh <tendrild>`);
  return {BASE_URL, TOKEN};
}

// A persistent-profile browser (as a person's: storage survives reloads) in a temporary folder named
// after the test; close() closes it and removes the folder.
export async function openBrowser(name, viewport = {width: 1280, height: 800}) {
  fs.mkdirSync(ARTIFACTS, {recursive: true});
  const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), `tendril-e2e-${name}-`));
  const context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: CHROMIUM, headless: true, viewport, args: CHROMIUM_ARGS});
  const page = context.pages()[0] ?? await context.newPage();
  const close = async () => {
    await context.close();
    fs.rmSync(userDataDir, {recursive: true, force: true});
  };
  return {context, page, close};
}

// Clicks the element once, in the same page task that sees it enabled. A check and a separate click
// race a page that turns STALE in between (its buttons are disabled while its data is old) and the
// click then lands on a disabled button; here the click cannot be lost, so no test needs to press again.
export async function clickWhenEnabled(page, selector, options = WAIT) {
  await page.waitForFunction((sel) => {
    const element = document.querySelector(sel);
    if (!element || element.disabled) return false;
    element.scrollIntoView({block: 'nearest'});
    element.click();
    return true;
  }, selector, options);
}
