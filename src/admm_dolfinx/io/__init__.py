"""Output: files written whole or not at all, the VTX writer and figures."""
