"""What README.md and docs/ quote from runs, rendered from the committed result files so that it cannot go stale.

- :mod:`~plm_highway.publish.blocks`: marked blocks in Markdown files and the one command that rewrites or checks
  them (``plm-highway docs render [--check]``);
- :mod:`~plm_highway.publish.renderers`: what each block shows, from which committed file.
"""
