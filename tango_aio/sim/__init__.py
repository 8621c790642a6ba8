"""Emulator of a Märzhäuser TANGO controller: wire model, controller logic and serving layers."""
