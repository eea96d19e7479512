//! Clap parsers for the library's named enums (`FromStr` plus strum's `VariantNames`), so `--help`
//! lists the names and the library needs no clap.

use clap::builder::{PossibleValuesParser, TypedValueParser};
use std::str::FromStr;
use strum::VariantNames;

/// Parse one of `T`'s names (kebab-case, as its `Display` writes them).
pub fn parse_name<T>() -> impl TypedValueParser<Value = T>
where
    T: FromStr + VariantNames + Clone + Send + Sync + 'static,
    T::Err: std::error::Error + Send + Sync + 'static,
{
    PossibleValuesParser::new(T::VARIANTS).try_map(|s| s.parse::<T>())
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio::encoder::ModelKind;
    use gonio::plan::{Spacing, Strategy};

    /// Every name parses, and prints back as itself (what scan.toml and --help rely on).
    fn round_trips<T: FromStr + VariantNames + std::fmt::Display>() {
        for name in T::VARIANTS {
            let value: T = name.parse().unwrap_or_else(|_| panic!("{name} does not parse"));
            assert_eq!(value.to_string(), *name);
        }
        assert!("no-such-name".parse::<T>().is_err());
    }

    #[test]
    fn the_library_enums_round_trip_through_their_names() {
        round_trips::<Strategy>();
        round_trips::<Spacing>();
        round_trips::<ModelKind>();
    }

    #[test]
    fn the_parser_refuses_unknown_names_and_lists_the_known_ones() {
        let cmd = clap::Command::new("t").arg(clap::Arg::new("s").long("s").value_parser(parse_name::<Strategy>()));
        let m = cmd
            .clone()
            .try_get_matches_from(["t", "--s", "mixture"])
            .expect("parses");
        assert_eq!(m.get_one::<Strategy>("s"), Some(&Strategy::Mixture));
        let err = cmd
            .try_get_matches_from(["t", "--s", "nope"])
            .expect_err("refused")
            .to_string();
        assert!(err.contains("auto") && err.contains("uniform"), "{err}");
    }
}
