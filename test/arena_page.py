"""Drive headless Chromium through its DevTools protocol: open a Planner Arena page, wait (real
time, up to 60 s) until its performance plot is drawn, screenshot it, print the plot's width
and the page's text as JSON.

Run by the Planner Arena venv's interpreter (it has ``websockets``), not imported by the tests:
``python arena_page.py CHROMIUM URL PNG DEBUG_PORT``. Shiny draws its plots over a websocket
after the page has loaded, which ``--screenshot`` and ``--virtual-time-budget`` do not wait for.
"""

import asyncio
import base64
import json
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request

CHROMIUM, URL, PNG, PORT = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])


async def main():
    import websockets
    profile = tempfile.mkdtemp()
    browser = subprocess.Popen([CHROMIUM, '--headless', '--no-sandbox', '--use-angle=swiftshader',
                                '--enable-unsafe-swiftshader', '--no-first-run',
                                f'--user-data-dir={profile}', '--window-size=1280,900',
                                f'--remote-debugging-port={PORT}', 'about:blank'],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(100):
            try:
                pages = json.load(urllib.request.urlopen(f'http://127.0.0.1:{PORT}/json'))
                page = next(p for p in pages if p['type'] == 'page')
                break
            except (OSError, StopIteration):
                await asyncio.sleep(0.2)
        async with websockets.connect(page['webSocketDebuggerUrl'], max_size=2 ** 26) as ws:
            ids = iter(range(1, 10 ** 6))

            async def call(method, **params):
                i = next(ids)
                await ws.send(json.dumps({'id': i, 'method': method, 'params': params}))
                while True:
                    msg = json.loads(await ws.recv())
                    if msg.get('id') == i:
                        return msg.get('result', {})

            await call('Page.navigate', url=URL)
            probe = ("(() => { const p = document.querySelector('#performance-plot img');"
                     " return p && p.naturalWidth > 0 ? p.naturalWidth : 0; })()")
            width, deadline = 0, time.monotonic() + 60
            while not width and time.monotonic() < deadline:
                await asyncio.sleep(0.5)
                width = (await call('Runtime.evaluate', expression=probe,
                                    returnByValue=True))['result'].get('value', 0)
            await asyncio.sleep(0.5)
            shot = await call('Page.captureScreenshot', format='png')
            open(PNG, 'wb').write(base64.b64decode(shot['data']))
            text = (await call('Runtime.evaluate', expression='document.body.innerText',
                               returnByValue=True))['result']['value']
            print(json.dumps({'plot_width': width, 'text': text}))
    finally:
        browser.kill()
        browser.wait()
        shutil.rmtree(profile, ignore_errors=True)


asyncio.run(main())
