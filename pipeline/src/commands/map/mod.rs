//! `pipeline map import | info | route`.

pub mod args;
mod import;
mod info;
mod options;
mod outputs;
mod route;

use anyhow::Result;

use super::Context;
use args::MapCommand;

pub fn run(ctx: &Context<'_>, command: &MapCommand) -> Result<()> {
    match command {
        MapCommand::Import(args) => import::import(ctx, args),
        MapCommand::Info(args) => info::info(ctx, args),
        MapCommand::Route(args) => route::route(ctx, args),
    }
}
