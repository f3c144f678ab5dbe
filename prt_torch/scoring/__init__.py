"""Scoring on the shipping path: the one rule ``prt eval``, ``prt compare``, the web check and the benches score with.

Below ``eval``, ``compare`` and ``web`` (their scoring kit), above ``player`` (its camera, renderer, tone map
and lighting are what is scored).
"""
