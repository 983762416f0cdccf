"""``sssbake view``: a loopback-only web page that shows one baked .glb with the three.js runtime."""
