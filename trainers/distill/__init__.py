"""The policy alone (``results/policy_alone/``): the hand-written teacher (approach planner +
docking law + brake, :class:`torchpark.experts.Teacher`) distilled by DAgger into one network
that drives the paper's env with nothing around it.

    python -m trainers.distill --preset policy_alone --out DIR [--resume | --overwrite]
                               [key=value ...]

The config (:mod:`trainers.distill.config`) is one tree: ``teacher``
(:class:`torchpark.experts.TeacherConfig`), ``student`` (the env, agent and model sections of
a PPO run) and ``dagger`` (the schedule and the fit), each field overridden in dot notation
(``python -m trainers.distill --help`` lists them with the preset's values). Presets:
``policy_alone`` (the committed agent) and ``smoke`` (seconds, for tests).

Each iteration (:func:`~trainers.distill.labels.label_iteration`) runs a driver in lots at
every occupancy level, half the starts near the goal: the teacher in the first (behaviour
cloning), the current student in the later ones (DAgger). It labels every state visited
with the teacher's control there. The labels join the data (the aggregate,
:mod:`trainers.distill.aggregate`) and the student is fitted to all of it (DAgger: Ross,
Gordon and Bagnell, 2011; :mod:`trainers.distill.fit`): ``dagger.epochs`` passes after the
first iteration, ``dagger.dagger_epochs`` after each later one. Half the rows drive with
Gaussian noise on the control (DART: Laskey et al., 2017), so the data holds the
corrections back to the teacher's path. With ``dagger.collision_weight`` W the states from
which the driver collided within ``dagger.collision_horizon`` steps weigh W in the fit;
with ``dagger.stall_weight`` W so do the states the student (not the teacher) then stalls
from: more than ``STALL_AWAY`` m from the goal, in an episode that goes on to the rollout's
end, whose next ``FREEZE_STEPS`` steps cover ``STALL_TRAVEL`` m or more and end within
``FREEZE_DISTANCE`` of where they began (the evaluator's freezing, :mod:`torchpark.runner`,
of a car that rocks between the two locks the teacher would hold).

The last millimetre asks for speeds of mm/s, a ten-thousandth of the range, and a steering
that lines the car up to 0.1 deg. The first iteration therefore also labels
``dagger.approach`` states per level drawn in the law's final approach (up to
``dagger.approach_reach`` m behind the goal, within the law's settled lateral and heading
errors, denser the closer), weighted ``dagger.approach_weight`` times a rollout state. The
student's speed passes through a power map
(:class:`torchpark.transforms.actions.PowerActionMap`, exponent 3): 1 mm/s is 0.058 of its
output's range, not 2e-4. Where the teacher turns a multi-point manoeuvre, states it drives
forwards from and states it reverses from look alike: the student outputs a gear and a
(speed, steer) pair per gear (:class:`torchpark.transforms.actions.GearActionMap`), fitted
to the label's gear and, for that gear's pair only, to the label. The teacher's planner
steers at five fixed angles and switches between them from state to state: with
``student.model.steer_bins`` each gear's steering is a choice among that many bins with an
offset in the bin (:class:`trainers.heads.BinnedGearHead`), fitted as a classification,
which keeps the angle a regression would average.

Written into ``--out``: ``checkpoint_final.pt`` (``python -m trainers.evaluate
DIR/checkpoint_final.pt``), ``checkpoint_best.pt`` (the iteration that scored best on the
checks from uniform starts, :data:`~trainers.distill.loop.BEST_BY`, on lots that are not the
evaluator's: DAgger's guarantee is for the best policy of the sequence, not the last) and
``dagger.csv``, per iteration the student's success at the three thresholds on the
yardstick (starts 0-6 m behind the goal, within 1 m and 0.6 rad of the slot axis, empty lot)
and from uniform starts at 0 % and 90 % occupancy. What each setting did:
research/experiments.md.

A run longer than a sitting resumes: after each iteration it saves its state
(``dagger_state.pt``, :mod:`trainers.distill.state`) and the iteration's labelled states
(``dagger_data/``), and the same command with ``--resume`` continues from the last finished
iteration, giving the checkpoints a run never stopped gives, bit for bit on the same machine
and thread count. ``dagger.iterations`` may be raised on resuming: more DAgger iterations on
the same data.
"""

from trainers.distill.config import DistillConfig, load_distill_config
from trainers.distill.loop import distill

__all__ = ["DistillConfig", "distill", "load_distill_config"]
