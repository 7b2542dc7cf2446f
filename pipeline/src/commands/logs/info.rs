//! `pipeline logs info`: a `ros2 bag info`-style summary (`logs::info`), or JSON.

use anyhow::Result;
use logs::Log;
use logs::info::{log_info, render, render_roles};

use super::InfoArgs;
use crate::commands::Context;
use crate::log_args::{log_error, topic_roles};

pub fn run(ctx: &Context<'_>, args: &InfoArgs) -> Result<()> {
    let log = Log::open(&args.log).map_err(log_error)?;
    let info = log_info(&log).map_err(log_error)?;
    let roles = topic_roles(
        &args.log,
        info.topics
            .iter()
            .map(|t| (t.name.as_str(), t.type_name.as_str(), t.encoding.as_str())),
        &args.roles.over(&ctx.config.logs.roles),
    )?;
    for warning in info.reader_warnings() {
        ctx.ui.warn(&warning);
    }
    if args.json {
        let mut value = serde_json::to_value(&info)?;
        if let Some(object) = value.as_object_mut() {
            object.insert("roles".into(), serde_json::to_value(&roles)?);
        }
        ctx.ui.result(&serde_json::to_string_pretty(&value)?);
    } else {
        let mut text = render(&info);
        text.push_str(&render_roles(&roles));
        ctx.ui.result(&text);
    }
    Ok(())
}
