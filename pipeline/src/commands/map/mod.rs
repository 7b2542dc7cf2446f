//! `pipeline map import | info | route`.

mod import;
mod info;
mod options;
mod route;

use anyhow::Result;

use super::Context;
use crate::cli::MapCommand;

pub fn run(ctx: &Context<'_>, command: &MapCommand) -> Result<()> {
    match command {
        MapCommand::Import(args) => import::import(ctx, args),
        MapCommand::Info(args) => info::info(ctx, args),
        MapCommand::Route(args) => route::route(ctx, args),
    }
}
