"""The web decoder and viewer (web/ in the checkout): tetweave_decoder.wasm (the C decoder core built by
web/build.py), its ES module, the three.js loader and the viewer page that `tetweave view` serves. No Python code:
a package only so that its files install with tetweave."""
