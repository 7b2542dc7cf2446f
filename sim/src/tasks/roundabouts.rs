//! What the tasks on a map's roundabouts share: their setup ([`RoundaboutSetup`]: the
//! roundabouts prepared once per map, routes and bird's-eye renderer of each), the scene
//! seen from the ego, and the ego's stacked bird's-eye frames.

use std::fmt::Debug;
use std::sync::Arc;

use maps::{Map, RoundaboutId};
use rand::Rng;

use super::{TaskId, TaskSetup, required_map};
use crate::env::ObservationSpec;
use crate::error::SimError;
use crate::observer::SceneObserver;
use crate::render::{BevConfig, BevRenderer, FrameStack};
use crate::roundabout::{LayoutConfig, RoundaboutLayout};
use crate::scene::Scene;
use crate::world::{CalibratedWorld, TrafficConfig, World};

/// Width of the navigable corridor along every route, m (a wide car).
const ROUTE_CORRIDOR_M: f64 = 2.0;

/// The settings a task on a map's roundabouts prepares its [`RoundaboutSetup`] from.
pub trait RoundaboutTaskConfig: Debug {
    /// The task the settings are of.
    const TASK: TaskId;

    /// Checks the settings, and gives the observer the task keeps of `observer` (see
    /// [`crate::observer::checked_observer`]).
    fn checked(
        &self,
        observer: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Option<Arc<dyn SceneObserver>>, SimError>;

    /// How the routes through each roundabout are laid out.
    fn layout(&self) -> &LayoutConfig;
    /// The bird's-eye view (its raster also decides what is navigable).
    fn bev(&self) -> &BevConfig;
    /// The shape of the task's observations.
    fn observation_spec(&self) -> ObservationSpec;
    /// The one roundabout of the map the task runs on; None (the default) runs it on every
    /// roundabout with a route through its ring.
    fn roundabout(&self) -> Option<RoundaboutId> {
        None
    }

    /// The traffic world's settings, to change in place.
    fn world_mut(&mut self) -> (&mut TrafficConfig, &mut LayoutConfig);

    /// The one roundabout the task runs on (None: every one), to change in place.
    fn roundabout_mut(&mut self) -> &mut Option<u32>;

    /// The settings in the traffic world `world` ([`crate::tasks::Task::in_world`]).
    fn in_world(&self, world: &CalibratedWorld) -> Self
    where
        Self: Clone,
    {
        let mut config = self.clone();
        let (traffic, layout) = config.world_mut();
        world.apply(traffic, layout);
        config
    }

    /// The settings on roundabout `id` only ([`crate::tasks::Task::on_roundabout`]).
    fn on_roundabout(&self, id: u32) -> Self
    where
        Self: Clone,
    {
        let mut config = self.clone();
        *config.roundabout_mut() = Some(id);
        config
    }
}

/// What a task on a map's roundabouts prepares once per map and shares with every
/// environment on it (read-only): its settings, the roundabouts with a route through their
/// ring, and the observer of a camera view.
#[derive(Debug)]
pub struct RoundaboutSetup<C> {
    pub(crate) config: C,
    pub(crate) roundabouts: RoundaboutSet,
    /// Draws the layers of a camera view.
    pub(crate) observer: Option<Arc<dyn SceneObserver>>,
}

impl<C: RoundaboutTaskConfig + Send + Sync + 'static> RoundaboutSetup<C> {
    /// Prepares every roundabout of `map` that has a route through its ring. Fails when
    /// there is none, or the configuration is invalid. A camera view needs its observer:
    /// see [`RoundaboutSetup::with_observer`].
    pub fn new(map: Arc<Map>, config: C) -> Result<Arc<Self>, SimError> {
        Self::with_observer(map, config, None)
    }

    /// As [`RoundaboutSetup::new`], with the observer that draws the layers of
    /// `view = "camera-segmentation"` (required by that view, unused by the others; its
    /// frame shape must be the `camera` table's).
    pub fn with_observer(
        map: Arc<Map>,
        config: C,
        observer: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Arc<Self>, SimError> {
        Self::prepare(Some(map), config, observer)
    }

    /// Prepares every roundabout of `map` that has a route through its ring for `config`
    /// (already validated, with its checked `observer`); fails when there is none.
    pub(crate) fn build(
        map: Arc<Map>,
        config: C,
        observer: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Arc<Self>, SimError> {
        let roundabouts = RoundaboutSet::with_roundabout(
            map,
            config.layout(),
            config.bev(),
            config.roundabout(),
        )?;
        Ok(Arc::new(RoundaboutSetup {
            config,
            roundabouts,
            observer,
        }))
    }

    pub fn map(&self) -> &Arc<Map> {
        self.roundabouts.map()
    }

    pub fn config(&self) -> &C {
        &self.config
    }

    pub fn layouts(&self) -> impl Iterator<Item = &Arc<RoundaboutLayout>> {
        self.roundabouts.layouts()
    }

    pub fn observation_spec(&self) -> ObservationSpec {
        self.config.observation_spec()
    }
}

impl<C: RoundaboutTaskConfig + Send + Sync + 'static> TaskSetup for RoundaboutSetup<C> {
    type Config = C;

    /// Checks `config` and its observer ([`RoundaboutTaskConfig::checked`]), then prepares
    /// every roundabout of `map` that has a route through its ring.
    fn prepare(
        map: Option<Arc<Map>>,
        config: C,
        observer: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Arc<Self>, SimError> {
        let map = required_map(map, C::TASK)?;
        let observer = config.checked(observer)?;
        Self::build(map, config, observer)
    }

    fn map(&self) -> &Map {
        self.roundabouts.map()
    }

    fn roundabouts(&self) -> Vec<u32> {
        self.layouts().map(|l| l.roundabout.0).collect()
    }
}

/// Every roundabout of a map that has a route from an entry through the ring to an exit,
/// with the bird's-eye renderer of its region (read-only, shared by every environment).
#[derive(Debug)]
pub struct RoundaboutSet {
    map: Arc<Map>,
    roundabouts: Vec<(Arc<RoundaboutLayout>, BevRenderer)>,
}

impl RoundaboutSet {
    /// Prepares the usable roundabouts of `map`; fails when there is none.
    pub fn new(map: Arc<Map>, layout: &LayoutConfig, view: &BevConfig) -> Result<Self, SimError> {
        Self::with_roundabout(map, layout, view, None)
    }

    /// Prepares roundabout `only` of `map`, or with None every usable one; fails when it is
    /// not in the map or has no route through its ring (with None: when none has).
    pub fn with_roundabout(
        map: Arc<Map>,
        layout: &LayoutConfig,
        view: &BevConfig,
        only: Option<RoundaboutId>,
    ) -> Result<Self, SimError> {
        let mut roundabouts = Vec::new();
        let mut problems = Vec::new();
        if let Some(id) = only
            && !map.roundabouts.contains_key(&id)
        {
            return Err(SimError::Map(format!("roundabout {id} is not in the map")));
        }
        for id in map
            .roundabouts
            .keys()
            .filter(|id| only.is_none_or(|o| o == **id))
        {
            // The world's drivers keep the roundabout rule: entering traffic gives way.
            if let Some(r) = map.roundabouts.get(id)
                && r.priority == maps::RoundaboutPriority::Entering
            {
                problems.push(format!(
                    "roundabout {id} gives entering traffic priority (traffic signals or give-way signs on its ring, from the map's tags); the simulator drives only rings where circulating traffic has priority"
                ));
                continue;
            }
            match RoundaboutLayout::new(&map, *id, layout) {
                Ok(layout) => {
                    // Routes rounded off at kinks may graze the mapped lanes' edges: a car's
                    // width along every route is navigable.
                    let renderer = BevRenderer::new(&map, layout.bounds, view.clone())?
                        .with_navigable_corridors(
                            layout.routes.iter().map(|r| r.path.outline()),
                            ROUTE_CORRIDOR_M,
                        );
                    roundabouts.push((Arc::new(layout), renderer));
                }
                Err(e) => problems.push(e.to_string()),
            }
        }
        if roundabouts.is_empty() {
            return Err(SimError::Map(if problems.is_empty() {
                "the map has no roundabout".into()
            } else {
                problems.join("; ")
            }));
        }
        Ok(RoundaboutSet { map, roundabouts })
    }

    pub fn map(&self) -> &Arc<Map> {
        &self.map
    }

    /// Never zero.
    pub fn len(&self) -> usize {
        self.roundabouts.len()
    }

    pub fn is_empty(&self) -> bool {
        self.roundabouts.is_empty()
    }

    pub fn layouts(&self) -> impl Iterator<Item = &Arc<RoundaboutLayout>> {
        self.roundabouts.iter().map(|(l, _)| l)
    }

    /// Roundabout `i` (clamped to the last one).
    pub fn layout(&self, i: usize) -> &Arc<RoundaboutLayout> {
        &self.roundabouts[i.min(self.roundabouts.len() - 1)].0
    }

    /// The renderer of roundabout `i` (clamped to the last one).
    pub fn renderer(&self, i: usize) -> &BevRenderer {
        &self.roundabouts[i.min(self.roundabouts.len() - 1)].1
    }

    /// A roundabout, one of its usable entries and one of that entry's routes, drawn
    /// uniformly in that order: `(roundabout, route)`.
    pub fn draw_route<R: Rng>(&self, rng: &mut R) -> (usize, usize) {
        let roundabout = pick(rng, self.roundabouts.len());
        let layout = self.layout(roundabout);
        let entries: Vec<usize> = layout.usable_entries().collect();
        // A layout exists only with at least one route, so `entries` is never empty.
        let entry = entries.get(pick(rng, entries.len())).copied().unwrap_or(0);
        let routes = &layout.routes_by_entry[entry];
        let route = routes.get(pick(rng, routes.len())).copied().unwrap_or(0);
        (roundabout, route)
    }
}

/// A uniform index below `n` from one draw (0 when `n` is 0).
fn pick<R: Rng>(rng: &mut R, n: usize) -> usize {
    ((rng.random::<f64>() * n as f64) as usize).min(n.saturating_sub(1))
}

/// The scene of `world` around its ego (None without an ego), times counted from
/// `start_time_s`; `ego_aggressiveness` is shown on the ego when the task has one.
pub fn ego_scene<'a>(
    map: &'a Map,
    world: &'a World,
    start_time_s: f64,
    ego_aggressiveness: Option<f64>,
) -> Option<Scene<'a>> {
    let ego = world.ego_index()?;
    let mut actors = world.actors();
    actors[ego].aggressiveness = ego_aggressiveness;
    Some(Scene {
        map,
        time_s: world.time_s() - start_time_s,
        actors,
        ego,
        ego_path: world.route(&world.vehicles()[ego]).path.outline(),
    })
}

/// The ego's stacked frames of one episode: bird's-eye frames, or frames drawn by a
/// [`SceneObserver`] (the camera-segmentation view). With rendering off nothing is drawn
/// and observations carry empty layers (for policies that do not read them).
#[derive(Debug, Clone)]
pub struct EgoView {
    frame: Vec<u8>,
    stack: FrameStack,
    rendering: bool,
    observer: Option<Arc<dyn SceneObserver>>,
}

impl EgoView {
    pub fn new(config: &BevConfig) -> Self {
        Self::spaced(config, 1)
    }

    /// A view whose stacked frames are `spacing` draws apart ([`FrameStack::spaced`]).
    pub fn spaced(config: &BevConfig, spacing: usize) -> Self {
        EgoView {
            frame: Vec::new(),
            stack: FrameStack::spaced(config.frame_len(), config.stack, spacing),
            rendering: true,
            observer: None,
        }
    }

    /// Frames drawn by `observer` instead of a bird's-eye renderer, `stack` of them.
    pub fn observed(observer: Arc<dyn SceneObserver>, stack: usize) -> Self {
        let (c, h, w) = observer.frame_shape();
        EgoView {
            frame: Vec::new(),
            stack: FrameStack::new(c * h * w, stack),
            rendering: true,
            observer: Some(observer),
        }
    }

    pub fn set_rendering(&mut self, on: bool) {
        self.rendering = on;
    }

    /// Draws `scene` (nothing without one: the previous frame is kept) and starts a new
    /// stack with it (`first`, at a reset) or pushes it.
    pub fn draw(&mut self, renderer: &BevRenderer, scene: Option<Scene<'_>>, first: bool) {
        self.draw_with(Some(renderer), scene, first);
    }

    /// As [`EgoView::draw`]; `renderer` is only used without an observer (and nothing is
    /// drawn without either).
    pub fn draw_with(
        &mut self,
        renderer: Option<&BevRenderer>,
        scene: Option<Scene<'_>>,
        first: bool,
    ) {
        if !self.rendering {
            return;
        }
        let frame_len = match (&self.observer, renderer) {
            (Some(o), _) => {
                let (c, h, w) = o.frame_shape();
                c * h * w
            }
            (None, Some(r)) => r.config().frame_len(),
            (None, None) => return,
        };
        if let Some(scene) = scene {
            match (&self.observer, renderer) {
                (Some(o), _) => o.observe(&scene, &mut self.frame),
                (None, Some(r)) => r.render(&scene, &mut self.frame),
                (None, None) => {}
            }
        }
        if self.frame.len() != frame_len {
            // Never drawn (no ego yet): an empty frame of the right size.
            self.frame.clear();
            self.frame.resize(frame_len, 0);
        }
        if first {
            self.stack.reset(&self.frame);
        } else {
            self.stack.push(&self.frame);
        }
    }

    /// The stacked layers of an observation (empty with rendering off).
    pub fn layers(&self) -> Vec<u8> {
        let mut layers = Vec::new();
        if self.rendering {
            self.stack.write(&mut layers);
        }
        layers
    }

    /// The newest frame (`[layer, row, column]`, see [`BevConfig::layers`]).
    pub fn newest(&self) -> &[u8] {
        self.stack.newest()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ring whose entering traffic has priority is refused by name, not driven by the
    /// wrong rule.
    #[test]
    fn a_ring_giving_entering_traffic_priority_is_refused() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../data/osm/montlake_roundabout.osm.pbf");
        let mut map = maps::import_file(&path, &Default::default()).expect("montlake imports");
        let layout = LayoutConfig::default();
        let view = BevConfig::default();
        assert!(RoundaboutSet::new(Arc::new(map.clone()), &layout, &view).is_ok());
        for r in map.roundabouts.values_mut() {
            r.priority = maps::RoundaboutPriority::Entering;
        }
        let Err(err) = RoundaboutSet::new(Arc::new(map), &layout, &view) else {
            panic!("a ring giving entering traffic priority was accepted");
        };
        let err = err.to_string();
        assert!(err.contains("entering traffic priority"), "{err}");
    }
}
