//! The 90 neural MERL fits bundled into the binary (host/data/merl-nbrdf, MIT licence: see its
//! LICENSE and README). Generated from the folder listing; a test checks that it lists every file.

/// (material name, JSON text), sorted by name.
pub(crate) const BUNDLED: &[(&str, &str)] = &[
    ("alum-bronze", include_str!("../../data/merl-nbrdf/alum-bronze.json")),
    ("aluminium", include_str!("../../data/merl-nbrdf/aluminium.json")),
    ("aventurnine", include_str!("../../data/merl-nbrdf/aventurnine.json")),
    ("beige-fabric", include_str!("../../data/merl-nbrdf/beige-fabric.json")),
    (
        "black-obsidian",
        include_str!("../../data/merl-nbrdf/black-obsidian.json"),
    ),
    (
        "black-oxidized-steel",
        include_str!("../../data/merl-nbrdf/black-oxidized-steel.json"),
    ),
    (
        "black-phenolic",
        include_str!("../../data/merl-nbrdf/black-phenolic.json"),
    ),
    (
        "black-soft-plastic",
        include_str!("../../data/merl-nbrdf/black-soft-plastic.json"),
    ),
    ("blue-acrylic", include_str!("../../data/merl-nbrdf/blue-acrylic.json")),
    ("blue-fabric", include_str!("../../data/merl-nbrdf/blue-fabric.json")),
    (
        "blue-metallic-paint",
        include_str!("../../data/merl-nbrdf/blue-metallic-paint.json"),
    ),
    (
        "blue-metallic-paint2",
        include_str!("../../data/merl-nbrdf/blue-metallic-paint2.json"),
    ),
    ("blue-rubber", include_str!("../../data/merl-nbrdf/blue-rubber.json")),
    ("cherry-235", include_str!("../../data/merl-nbrdf/cherry-235.json")),
    ("chrome", include_str!("../../data/merl-nbrdf/chrome.json")),
    ("chrome-steel", include_str!("../../data/merl-nbrdf/chrome-steel.json")),
    (
        "colonial-maple-223",
        include_str!("../../data/merl-nbrdf/colonial-maple-223.json"),
    ),
    (
        "color-changing-paint1",
        include_str!("../../data/merl-nbrdf/color-changing-paint1.json"),
    ),
    (
        "color-changing-paint2",
        include_str!("../../data/merl-nbrdf/color-changing-paint2.json"),
    ),
    (
        "color-changing-paint3",
        include_str!("../../data/merl-nbrdf/color-changing-paint3.json"),
    ),
    (
        "dark-blue-paint",
        include_str!("../../data/merl-nbrdf/dark-blue-paint.json"),
    ),
    (
        "dark-red-paint",
        include_str!("../../data/merl-nbrdf/dark-red-paint.json"),
    ),
    (
        "dark-specular-fabric",
        include_str!("../../data/merl-nbrdf/dark-specular-fabric.json"),
    ),
    ("delrin", include_str!("../../data/merl-nbrdf/delrin.json")),
    (
        "fruitwood-241",
        include_str!("../../data/merl-nbrdf/fruitwood-241.json"),
    ),
    (
        "gold-metallic-paint",
        include_str!("../../data/merl-nbrdf/gold-metallic-paint.json"),
    ),
    (
        "gold-metallic-paint2",
        include_str!("../../data/merl-nbrdf/gold-metallic-paint2.json"),
    ),
    (
        "gold-metallic-paint3",
        include_str!("../../data/merl-nbrdf/gold-metallic-paint3.json"),
    ),
    ("gold-paint", include_str!("../../data/merl-nbrdf/gold-paint.json")),
    ("gray-plastic", include_str!("../../data/merl-nbrdf/gray-plastic.json")),
    (
        "grease-covered-steel",
        include_str!("../../data/merl-nbrdf/grease-covered-steel.json"),
    ),
    (
        "green-acrylic",
        include_str!("../../data/merl-nbrdf/green-acrylic.json"),
    ),
    ("green-fabric", include_str!("../../data/merl-nbrdf/green-fabric.json")),
    ("green-latex", include_str!("../../data/merl-nbrdf/green-latex.json")),
    (
        "green-metallic-paint",
        include_str!("../../data/merl-nbrdf/green-metallic-paint.json"),
    ),
    (
        "green-metallic-paint2",
        include_str!("../../data/merl-nbrdf/green-metallic-paint2.json"),
    ),
    (
        "green-plastic",
        include_str!("../../data/merl-nbrdf/green-plastic.json"),
    ),
    ("hematite", include_str!("../../data/merl-nbrdf/hematite.json")),
    (
        "ipswich-pine-221",
        include_str!("../../data/merl-nbrdf/ipswich-pine-221.json"),
    ),
    (
        "light-brown-fabric",
        include_str!("../../data/merl-nbrdf/light-brown-fabric.json"),
    ),
    (
        "light-red-paint",
        include_str!("../../data/merl-nbrdf/light-red-paint.json"),
    ),
    (
        "maroon-plastic",
        include_str!("../../data/merl-nbrdf/maroon-plastic.json"),
    ),
    ("natural-209", include_str!("../../data/merl-nbrdf/natural-209.json")),
    (
        "neoprene-rubber",
        include_str!("../../data/merl-nbrdf/neoprene-rubber.json"),
    ),
    ("nickel", include_str!("../../data/merl-nbrdf/nickel.json")),
    ("nylon", include_str!("../../data/merl-nbrdf/nylon.json")),
    ("orange-paint", include_str!("../../data/merl-nbrdf/orange-paint.json")),
    ("pearl-paint", include_str!("../../data/merl-nbrdf/pearl-paint.json")),
    ("pink-fabric", include_str!("../../data/merl-nbrdf/pink-fabric.json")),
    ("pink-fabric2", include_str!("../../data/merl-nbrdf/pink-fabric2.json")),
    ("pink-felt", include_str!("../../data/merl-nbrdf/pink-felt.json")),
    ("pink-jasper", include_str!("../../data/merl-nbrdf/pink-jasper.json")),
    ("polyethylene", include_str!("../../data/merl-nbrdf/polyethylene.json")),
    (
        "polyurethane-foam",
        include_str!("../../data/merl-nbrdf/polyurethane-foam.json"),
    ),
    ("pure-rubber", include_str!("../../data/merl-nbrdf/pure-rubber.json")),
    ("purple-paint", include_str!("../../data/merl-nbrdf/purple-paint.json")),
    ("pvc", include_str!("../../data/merl-nbrdf/pvc.json")),
    ("red-fabric", include_str!("../../data/merl-nbrdf/red-fabric.json")),
    ("red-fabric2", include_str!("../../data/merl-nbrdf/red-fabric2.json")),
    (
        "red-metallic-paint",
        include_str!("../../data/merl-nbrdf/red-metallic-paint.json"),
    ),
    ("red-phenolic", include_str!("../../data/merl-nbrdf/red-phenolic.json")),
    (
        "red-specular-plastic",
        include_str!("../../data/merl-nbrdf/red-specular-plastic.json"),
    ),
    (
        "silicon-nitrade",
        include_str!("../../data/merl-nbrdf/silicon-nitrade.json"),
    ),
    (
        "silver-metallic-paint",
        include_str!("../../data/merl-nbrdf/silver-metallic-paint.json"),
    ),
    (
        "silver-metallic-paint2",
        include_str!("../../data/merl-nbrdf/silver-metallic-paint2.json"),
    ),
    (
        "special-walnut-224",
        include_str!("../../data/merl-nbrdf/special-walnut-224.json"),
    ),
    (
        "specular-black-phenolic",
        include_str!("../../data/merl-nbrdf/specular-black-phenolic.json"),
    ),
    (
        "specular-blue-phenolic",
        include_str!("../../data/merl-nbrdf/specular-blue-phenolic.json"),
    ),
    (
        "specular-maroon-phenolic",
        include_str!("../../data/merl-nbrdf/specular-maroon-phenolic.json"),
    ),
    (
        "specular-orange-phenolic",
        include_str!("../../data/merl-nbrdf/specular-orange-phenolic.json"),
    ),
    (
        "specular-red-phenolic",
        include_str!("../../data/merl-nbrdf/specular-red-phenolic.json"),
    ),
    (
        "specular-violet-phenolic",
        include_str!("../../data/merl-nbrdf/specular-violet-phenolic.json"),
    ),
    (
        "specular-white-phenolic",
        include_str!("../../data/merl-nbrdf/specular-white-phenolic.json"),
    ),
    (
        "specular-yellow-phenolic",
        include_str!("../../data/merl-nbrdf/specular-yellow-phenolic.json"),
    ),
    ("ss440", include_str!("../../data/merl-nbrdf/ss440.json")),
    ("steel", include_str!("../../data/merl-nbrdf/steel.json")),
    ("teflon", include_str!("../../data/merl-nbrdf/teflon.json")),
    (
        "tungsten-carbide",
        include_str!("../../data/merl-nbrdf/tungsten-carbide.json"),
    ),
    (
        "two-layer-gold",
        include_str!("../../data/merl-nbrdf/two-layer-gold.json"),
    ),
    (
        "two-layer-silver",
        include_str!("../../data/merl-nbrdf/two-layer-silver.json"),
    ),
    (
        "white-acrylic",
        include_str!("../../data/merl-nbrdf/white-acrylic.json"),
    ),
    (
        "white-diffuse-bball",
        include_str!("../../data/merl-nbrdf/white-diffuse-bball.json"),
    ),
    ("white-fabric", include_str!("../../data/merl-nbrdf/white-fabric.json")),
    (
        "white-fabric2",
        include_str!("../../data/merl-nbrdf/white-fabric2.json"),
    ),
    ("white-marble", include_str!("../../data/merl-nbrdf/white-marble.json")),
    ("white-paint", include_str!("../../data/merl-nbrdf/white-paint.json")),
    (
        "yellow-matte-plastic",
        include_str!("../../data/merl-nbrdf/yellow-matte-plastic.json"),
    ),
    ("yellow-paint", include_str!("../../data/merl-nbrdf/yellow-paint.json")),
    (
        "yellow-phenolic",
        include_str!("../../data/merl-nbrdf/yellow-phenolic.json"),
    ),
    (
        "yellow-plastic",
        include_str!("../../data/merl-nbrdf/yellow-plastic.json"),
    ),
];
