"""highway-env's Kinematics observation without pandas.

``KinematicObservation.observe`` builds a pandas DataFrame from the observed vehicles'
``to_dict()`` rows, normalises its columns and reads the values back: a few milliseconds
per call, as much as a whole simulation step of our traffic core. :class:`FastKinematicObservation`
takes the same rows, the same vehicles (highway-env's ``close_objects_to``) and the same
normalisation (highway-env's own ``normalize_obs``, given numpy columns instead of pandas
ones), so its arrays are highway-env's, bit for bit (``tests/test_fastroad.py`` compares
them over whole episodes).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from highway_env.envs.common.observation import KinematicObservation

if TYPE_CHECKING:
    from highway_env.envs.common.abstract import AbstractEnv
    from highway_env.vehicle.objects import RoadObject


class FastKinematicObservation(KinematicObservation):
    """highway-env's ``Kinematics`` observation (same options, same values), built with numpy.

    :raises ValueError: if a feature is named twice (pandas would give the column twice)
    """

    def __init__(self, env: AbstractEnv, **kwargs: Any) -> None:
        super().__init__(env, **kwargs)
        if len(set(self.features)) != len(self.features):
            raise ValueError(f"observation features must be distinct names (got {self.features})")

    def observed(self) -> list[RoadObject]:
        """The observer and the objects of the observation's rows, in row order (highway-env's
        ``close_objects_to`` with this observation's options)."""
        ego = self.observer_vehicle
        close = self.env.road.close_objects_to(
            ego, self.env.PERCEPTION_DISTANCE, count=self.vehicles_count - 1, see_behind=self.see_behind,
            sort=self.order == "sorted", vehicles_only=not self.include_obstacles,
        )
        return [ego, *(close[-self.vehicles_count + 1:] if close else [])]

    def observe(self) -> np.ndarray:
        if not self.env.road:
            return np.zeros(self.space().shape)
        ego, *close = self.observed()
        records = [ego.to_dict()]
        if close:
            origin = ego if not self.absolute else None
            records += [v.to_dict(origin, observe_intentions=self.observe_intentions) for v in close]
        # one column per feature, as pandas builds it from the records (a key some rows lack is
        # NaN there; one that no row has is pandas' KeyError)
        missing = [f for f in self.features if not any(f in r for r in records)]
        if missing:
            raise KeyError(f"observation features {missing} are not in the vehicles' to_dict() rows")
        columns = {f: np.array([r.get(f, np.nan) for r in records]) for f in self.features}
        if self.normalize:
            columns = self.normalize_obs(columns)
        obs = np.zeros((max(self.vehicles_count, len(records)), len(self.features)))
        for k, f in enumerate(self.features):
            obs[: len(records), k] = columns[f]
        if self.order == "shuffled":
            self.env.np_random.shuffle(obs[1:])
        return obs.astype(self.space().dtype)
