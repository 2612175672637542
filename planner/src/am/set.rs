//! Engines for one team, objective and settings, one per obstacle count:
//! the unit a daemon preloads and a benchmark reuses (building an engine
//! factors its KKT systems, a start-up cost rather than a per-plan one).

use super::engine::{Engine, EngineError, Objective};
use super::settings::AmSettings;
use crate::problem::Team;

/// The engines of one (team, objective, settings), indexed by obstacle
/// count, built on first use or preloaded.
#[derive(Debug, Clone)]
pub struct EngineSet {
    team: Team,
    objective: Objective,
    settings: AmSettings,
    /// Index: the obstacle count.
    engines: Vec<Option<Engine>>,
}

impl EngineSet {
    /// An empty set: engines are built by [`EngineSet::engine`] on first use.
    pub fn new(team: &Team, objective: Objective, settings: AmSettings) -> Self {
        Self { team: team.clone(), objective, settings, engines: Vec::new() }
    }

    /// A set with the engines for every obstacle count `0..=max_obstacles`
    /// built, so that [`EngineSet::get`] finds them.
    pub fn preloaded(
        team: &Team,
        objective: Objective,
        settings: AmSettings,
        max_obstacles: usize,
    ) -> Result<Self, EngineError> {
        let mut set = Self::new(team, objective, settings);
        for m in 0..=max_obstacles {
            set.engine(m)?;
        }
        Ok(set)
    }

    /// Whether this is the set of `team`, `objective` and `settings`.
    pub fn is_for(&self, team: &Team, objective: Objective, settings: &AmSettings) -> bool {
        self.team == *team && self.objective == objective && self.settings == *settings
    }

    /// The set of `team`, `objective` and `settings` in `sets`, added
    /// (empty) if there is none yet: planners that meet several team
    /// shapes keep one set per shape.
    pub fn find_or_add<'s>(
        sets: &'s mut Vec<EngineSet>,
        team: &Team,
        objective: Objective,
        settings: AmSettings,
    ) -> &'s mut EngineSet {
        let index = match sets.iter().position(|s| s.is_for(team, objective, &settings)) {
            Some(i) => i,
            None => {
                sets.push(EngineSet::new(team, objective, settings));
                sets.len() - 1
            }
        };
        &mut sets[index]
    }

    /// The team.
    pub fn team(&self) -> &Team {
        &self.team
    }

    /// The engine for `obstacles` obstacles, built now if it was not yet.
    pub fn engine(&mut self, obstacles: usize) -> Result<&Engine, EngineError> {
        if self.engines.len() <= obstacles {
            self.engines.resize(obstacles + 1, None);
        }
        let slot = &mut self.engines[obstacles];
        if slot.is_none() {
            *slot = Some(Engine::new(&self.team, obstacles, self.objective, self.settings)?);
        }
        Ok(slot.as_ref().expect("built above"))
    }

    /// The engine for `obstacles` obstacles if it was built.
    pub fn get(&self, obstacles: usize) -> Option<&Engine> {
        self.engines.get(obstacles).and_then(Option::as_ref)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::Dim;

    #[test]
    fn a_preloaded_set_has_every_count_and_builds_others_on_demand() {
        let team = Team::default_for(Dim::Two, 4);
        let mut set = EngineSet::preloaded(&team, Objective::Projection, AmSettings::safety_filter(), 2).unwrap();
        assert!((0..=2).all(|m| set.get(m).is_some_and(|e| e.obstacles() == m)));
        assert!(set.get(3).is_none());
        assert_eq!(set.engine(5).unwrap().obstacles(), 5);
        assert!(set.get(4).is_none() && set.get(5).is_some());
        assert!(set.is_for(&team, Objective::Projection, &AmSettings::safety_filter()));
        assert!(!set.is_for(&team, Objective::smoothness(), &AmSettings::safety_filter()));
        // One set per (team, objective, settings) in a list.
        let mut sets = Vec::new();
        EngineSet::find_or_add(&mut sets, &team, Objective::Projection, AmSettings::safety_filter()).engine(1).unwrap();
        let again = EngineSet::find_or_add(&mut sets, &team, Objective::Projection, AmSettings::safety_filter());
        assert!(again.get(1).is_some(), "the same set is found again");
        let other = Team::default_for(Dim::Two, 5);
        EngineSet::find_or_add(&mut sets, &other, Objective::Projection, AmSettings::safety_filter());
        assert_eq!(sets.len(), 2);
    }
}
