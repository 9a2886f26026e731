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

from dt_highway.config import ConfigError

if TYPE_CHECKING:
    from highway_env.envs.common.abstract import AbstractEnv
    from highway_env.vehicle.objects import RoadObject


def check_feature_names(where: str, type_name: str, features: list[str], features_range: dict[str, Any] | None,
                        columns: set[str], also: tuple[str, ...] = (), own: tuple[str, ...] = ()) -> None:
    """Refuse ``features`` and ``features_range`` keys that no vehicle row has: highway-env leaves an
    unknown ``features_range`` key (and ``OccupancyGrid`` an unknown feature) silently unused.

    :param where: the table's dotted key, for the message (``highway.observation``)
    :param type_name: the observation type, for the message
    :param features: the features read from the rows
    :param features_range: its normalisation ranges (None: not checked)
    :param columns: the keys of the vehicles' ``to_dict()`` rows
    :param also: names the type reads beside the rows' columns (``OccupancyGrid``'s ``on_road``)
    :param own: columns the type adds itself (``OverlayKinematics``' ``marked``): not a feature to
        name, a range for them is taken (and unused)
    :raises ConfigError: one line naming the unknown names and the known ones
    """
    named_own = [name for name in features if name in own]
    if named_own:
        one = len(named_own) == 1
        raise ConfigError(f"{where}.features: {_names(named_own)} {'is a column' if one else 'are columns'} the "
                          f"observation adds itself (type '{type_name}'): leave {'it' if one else 'them'} out")
    known = columns | set(also)
    for key, names, allowed in (("features", list(features), known),
                                ("features_range", list(features_range or {}), known | set(own))):
        unknown = [name for name in names if name not in allowed]
        if unknown:
            what = "is not a feature" if len(unknown) == 1 else "are not features"
            raise ConfigError(f"{where}.{key}: {_names(unknown)} {what} of type '{type_name}' "
                              f"(its features: {', '.join(sorted(known))})")


def _names(names: list[str]) -> str:
    return ", ".join(map(repr, names))


class FastKinematicObservation(KinematicObservation):
    """highway-env's ``Kinematics`` observation (same options, same values), built with numpy.

    :param env: the environment observed
    :param kwargs: highway-env's ``KinematicObservation`` options (``features``, ``vehicles_count``,
        ``features_range``, ``absolute``, ``order``, ``normalize``, ``see_behind``, ...)
    :raises ValueError: if a feature is named twice (pandas would give the column twice)
    :raises ConfigError: at the first observation, for a feature or ``features_range`` key that is
        not a column of the vehicles' ``to_dict()`` rows
    """

    TYPE_NAME = "Kinematics"
    """The ``type`` this observation is made from, for messages"""
    OWN_COLUMNS: tuple[str, ...] = ()
    """Columns the observation may add to the rows' features itself (its subclasses')"""

    def __init__(self, env: AbstractEnv, **kwargs: Any) -> None:
        super().__init__(env, **kwargs)
        if len(set(self.features)) != len(self.features):
            raise ValueError(f"observation features must be distinct names (got {self.features})")
        self.names_from = "highway.observation"
        """Where the feature names come from, for the message of a name no row has"""
        self.check_ranges = True
        """Whether a ``features_range`` key no row has is refused (a policy's trained observation: not)"""
        self._names_checked = False

    def observed(self) -> list[RoadObject]:
        """The observer and the objects of the observation's rows, in row order (highway-env's
        ``close_objects_to`` with this observation's options).

        :return: the observer vehicle first, then the observed objects
        """
        ego = self.observer_vehicle
        close = self.env.road.close_objects_to(
            ego, self.env.PERCEPTION_DISTANCE, count=self.vehicles_count - 1, see_behind=self.see_behind,
            sort=self.order == "sorted", vehicles_only=not self.include_obstacles,
        )
        return [ego, *(close[-self.vehicles_count + 1:] if close else [])]

    def observe(self) -> np.ndarray:
        """The kinematic observation of the ego and the vehicles it observes.

        :return: highway-env's Kinematics array (same values, computed without its DataFrame)
        """
        if not self.env.road:
            return np.zeros(self.space().shape)
        ego, *close = self.observed()
        records = [ego.to_dict()]
        if close:
            origin = ego if not self.absolute else None
            records += [v.to_dict(origin, observe_intentions=self.observe_intentions) for v in close]
        # one column per feature, as pandas builds it from the records (a key some rows lack is
        # NaN there; one that no row has is pandas' KeyError, a configuration error here)
        if not self._names_checked:
            check_feature_names(self.names_from, self.TYPE_NAME, self.features,
                                self.features_range if self.check_ranges else None, set().union(*records),
                                own=self.OWN_COLUMNS)
            self._names_checked = True
        columns = {f: np.array([r.get(f, np.nan) for r in records]) for f in self.features}
        if self.normalize:
            columns = self.normalize_obs(columns)
        obs = np.zeros((max(self.vehicles_count, len(records)), len(self.features)))
        for k, f in enumerate(self.features):
            obs[: len(records), k] = columns[f]
        if self.order == "shuffled":
            self.env.np_random.shuffle(obs[1:])
        return obs.astype(self.space().dtype)
