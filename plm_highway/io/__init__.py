"""Every file the project writes goes through here: safe, atomic outputs."""

from plm_highway.io.atomic import atomic_path, write_text_atomic

__all__ = ["atomic_path", "write_text_atomic"]
