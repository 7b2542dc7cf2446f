//! The settings tables of every task of the registry side by side (a config file's
//! `[agent.<table>]`s), so that a task finds its own by type ([`super::Task::table`]).

use super::insertion::InsertionConfig;
use super::obstacle::ObstacleConfig;
use super::ring_driving::RingDrivingConfig;
use super::route::RouteConfig;

/// Every task's settings table, borrowed.
#[derive(Debug, Clone, Copy)]
pub struct Tables<'a> {
    pub insertion: &'a InsertionConfig,
    pub route: &'a RouteConfig,
    pub ring_driving: &'a RingDrivingConfig,
    pub obstacle: &'a ObstacleConfig,
}

/// Every task's settings table, to change in place.
#[derive(Debug)]
pub struct TablesMut<'a> {
    pub insertion: &'a mut InsertionConfig,
    pub route: &'a mut RouteConfig,
    pub ring_driving: &'a mut RingDrivingConfig,
    pub obstacle: &'a mut ObstacleConfig,
}
