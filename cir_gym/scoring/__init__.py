"""Scoring: policies resolved by name, ranked tables, the leaderboard and its page, sweeps.

:mod:`~cir_gym.scoring.policies` (a name → an object with SB3's ``predict``: controllers,
``tuned:``, ``agent:``, ``plugin:``), :mod:`~cir_gym.scoring.tables`,
:mod:`~cir_gym.scoring.leaderboard` (the main job), :mod:`~cir_gym.scoring.page`,
:mod:`~cir_gym.scoring.sweep`, :mod:`~cir_gym.scoring.plotting` and
:mod:`~cir_gym.scoring.identify`. Below the command line (:mod:`cir_gym.cli`), above the
agents, the controllers and the evaluator; importing it imports none of its modules.
"""
