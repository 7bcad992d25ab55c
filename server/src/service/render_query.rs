//! The query string of `GET /v1/assets/{id}/render`: the keys of the `POST` render body as URL
//! parameters, so a link is also an image (docs/protocol.md, "Render links").
//!
//! [`body_from_query`] turns the parameters into the JSON object a `POST` body would be, built in
//! a fixed key order whatever the parameters' order: [`RenderBody`](super::http::RenderBody)
//! then parses and checks it like any body, and its serialisation is the canonical form the
//! response's `ETag` hashes. Only the spelling is checked here (each error names its
//! parameter); ranges and conflicts are the body parser's, with the `POST` path's messages.

use serde_json::{Map, Number, Value};

use super::error::AppError;

/// The view's parameters. `eye` or the orbit form (`az`, `el`, `dist`) places the eye.
const VIEW_KEYS: &[&str] = &[
    "eye", "az", "el", "dist", "target", "up", "yfov_deg", "width", "height",
];
/// The output parameters (the render body's `background`, `format` and `quality`).
const OUTPUT_KEYS: &[&str] = &["background", "format", "quality"];

/// The parameters the query accepts, in the canonical order.
pub fn keys() -> impl Iterator<Item = &'static str> {
    VIEW_KEYS
        .iter()
        .chain(OUTPUT_KEYS)
        .chain(lumigraph_core::quality::Quality::FIELDS)
        .copied()
}

fn invalid(key: &str, what: &str, value: &str) -> AppError {
    AppError::Invalid(format!("parameter `{key}`: expected {what}, got {value:?}"))
}

fn number(key: &str, value: &str) -> Result<f64, AppError> {
    value
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .ok_or_else(|| invalid(key, "a finite number", value))
}

fn vec3(key: &str, value: &str) -> Result<[f64; 3], AppError> {
    let parts: Vec<&str> = value.split(',').collect();
    let what = "three finite numbers separated by commas (x,y,z)";
    if parts.len() != 3 {
        return Err(invalid(key, what, value));
    }
    let mut out = [0.0; 3];
    for (slot, part) in out.iter_mut().zip(parts) {
        *slot = part
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| invalid(key, what, value))?;
    }
    Ok(out)
}

fn whole(key: &str, value: &str) -> Result<u32, AppError> {
    value
        .parse::<u32>()
        .map_err(|_| invalid(key, "a whole number", value))
}

/// A quality key's value as the JSON a body would carry: `method`, `layers`, `state` and
/// `uv_filter` strings, `light` a vector, the others numbers
/// (whole numbers stay integers, so `lod=12.5` gets the body's type error).
fn quality_value(key: &str, value: &str) -> Result<Value, AppError> {
    if matches!(key, "method" | "layers" | "state" | "uv_filter") {
        return Ok(Value::String(value.to_owned()));
    }
    if key == "light" {
        return Ok(json3(vec3(key, value)?));
    }
    if let Ok(n) = value.parse::<u64>() {
        return Ok(Value::Number(n.into()));
    }
    if let Ok(n) = value.parse::<i64>() {
        return Ok(Value::Number(n.into()));
    }
    let n = number(key, value)?;
    Number::from_f64(n)
        .map(Value::Number)
        .ok_or_else(|| invalid(key, "a finite number", value))
}

fn json3(v: [f64; 3]) -> Value {
    Value::Array(
        v.iter()
            .map(|x| Number::from_f64(*x).map_or(Value::Null, Value::Number))
            .collect(),
    )
}

/// The eye of the viewer's orbit camera: `dist` from `target` at azimuth `az` (degrees, about
/// +y from +z towards +x) and elevation `el` (degrees above the x-z plane). The web viewer
/// computes the same.
pub fn orbit_eye(target: [f64; 3], az_deg: f64, el_deg: f64, dist: f64) -> [f64; 3] {
    let (az, el) = (az_deg.to_radians(), el_deg.to_radians());
    // The viewer's order of operations, so both sides round alike.
    [
        target[0] + el.cos() * az.sin() * dist,
        target[1] + el.sin() * dist,
        target[2] + el.cos() * az.cos() * dist,
    ]
}

/// The render body of a `GET` render's query parameters (see the module doc).
///
/// # Errors
/// [`AppError::Invalid`] naming the parameter: unknown or repeated, malformed, missing, or the
/// view given both as `eye` and in the orbit form.
pub fn body_from_query(pairs: &[(String, String)]) -> Result<Map<String, Value>, AppError> {
    let mut given: Map<String, Value> = Map::new();
    for (key, value) in pairs {
        if key == "depth" {
            return Err(AppError::Invalid(
                "parameter `depth`: a render link answers one image; ask for depth with \
                 POST /v1/assets/{id}/render"
                    .to_owned(),
            ));
        }
        if !keys().any(|k| k == key) {
            return Err(AppError::Invalid(format!(
                "unknown parameter {key:?}: expected {}",
                keys().collect::<Vec<_>>().join(", ")
            )));
        }
        if given
            .insert(key.clone(), Value::String(value.clone()))
            .is_some()
        {
            return Err(AppError::Invalid(format!(
                "parameter `{key}` is given more than once"
            )));
        }
    }
    let text = |key: &str| given.get(key).and_then(Value::as_str);
    let required = |key: &str| {
        text(key).ok_or_else(|| AppError::Invalid(format!("missing parameter `{key}`")))
    };

    let target = vec3("target", required("target")?)?;
    let orbit = ["az", "el", "dist"].map(&text);
    let eye = match (text("eye"), orbit) {
        (Some(_), [None, None, None]) => vec3("eye", required("eye")?)?,
        (Some(_), _) => {
            return Err(AppError::Invalid(
                "give the eye as `eye` or as `az`, `el`, `dist`, not both".to_owned(),
            ));
        }
        (None, [Some(az), Some(el), Some(dist)]) => {
            let dist_value = number("dist", dist)?;
            if dist_value <= 0.0 {
                return Err(invalid("dist", "a distance above 0", dist));
            }
            orbit_eye(target, number("az", az)?, number("el", el)?, dist_value)
        }
        (None, [None, None, None]) => {
            return Err(AppError::Invalid(
                "missing parameter `eye` (or `az`, `el`, `dist` with `target`)".to_owned(),
            ));
        }
        (None, _) => {
            return Err(AppError::Invalid(
                "the orbit form needs all of `az`, `el` and `dist`".to_owned(),
            ));
        }
    };
    let mut view = Map::new();
    view.insert("eye".to_owned(), json3(eye));
    view.insert("target".to_owned(), json3(target));
    if let Some(up) = text("up") {
        view.insert("up".to_owned(), json3(vec3("up", up)?));
    }
    let yfov = number("yfov_deg", required("yfov_deg")?)?;
    view.insert(
        "yfov_deg".to_owned(),
        Number::from_f64(yfov).map_or(Value::Null, Value::Number),
    );
    for side in ["width", "height"] {
        view.insert(side.to_owned(), whole(side, required(side)?)?.into());
    }

    let mut body = Map::new();
    body.insert("view".to_owned(), Value::Object(view));
    if let Some(bg) = text("background") {
        let what = "four whole numbers 0..=255 separated by commas (r,g,b,a)";
        let channels: Vec<u8> = bg
            .split(',')
            .map(str::parse::<u8>)
            .collect::<Result<_, _>>()
            .map_err(|_| invalid("background", what, bg))?;
        if channels.len() != 4 {
            return Err(invalid("background", what, bg));
        }
        body.insert(
            "background".to_owned(),
            Value::Array(channels.into_iter().map(Value::from).collect()),
        );
    }
    if let Some(format) = text("format") {
        body.insert("format".to_owned(), Value::String(format.to_owned()));
    }
    if let Some(quality) = text("quality") {
        let q = whole("quality", quality)?;
        if !(1..=100).contains(&q) {
            return Err(AppError::Invalid(format!(
                "quality must be in 1..=100, got {q}"
            )));
        }
        body.insert("quality".to_owned(), q.into());
    }
    for key in lumigraph_core::quality::Quality::FIELDS {
        if let Some(value) = text(key) {
            body.insert((*key).to_owned(), quality_value(key, value)?);
        }
    }
    Ok(body)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pairs(query: &str) -> Vec<(String, String)> {
        query
            .split('&')
            .filter_map(|p| p.split_once('='))
            .map(|(k, v)| (k.to_owned(), v.to_owned()))
            .collect()
    }

    fn message(query: &str) -> String {
        match body_from_query(&pairs(query)) {
            Err(AppError::Invalid(m)) => m,
            other => panic!("{query}: expected Invalid, got {other:?}"),
        }
    }

    const VIEW: &str = "eye=0,0,3&target=0,0,0&yfov_deg=40&width=64&height=48";

    #[test]
    fn the_body_does_not_depend_on_the_parameters_order() {
        let a =
            body_from_query(&pairs(&format!("{VIEW}&lod=12&step=0.02&format=png"))).expect("valid");
        let b = body_from_query(&pairs(
            "step=0.02&format=png&height=48&width=64&lod=12&yfov_deg=40.0&target=0,0,0&eye=0,0,3",
        ))
        .expect("valid");
        assert_eq!(
            serde_json::to_string(&a).expect("json"),
            serde_json::to_string(&b).expect("json")
        );
        assert_eq!(a["lod"], serde_json::json!(12));
        assert_eq!(a["view"]["yfov_deg"], serde_json::json!(40.0));
    }

    #[test]
    fn the_orbit_form_places_the_eye_like_the_viewer() {
        let body = body_from_query(&pairs(
            "az=90&el=0&dist=2&target=1,0,0&yfov_deg=40&width=8&height=8",
        ))
        .expect("valid");
        let eye: Vec<f64> = body["view"]["eye"]
            .as_array()
            .expect("eye")
            .iter()
            .filter_map(Value::as_f64)
            .collect();
        // sin/cos of 90° in f64 leave ~1e-16; the tolerance is far above that, far below a unit.
        for (got, want) in eye.iter().zip([3.0, 0.0, 0.0]) {
            assert!((got - want).abs() < 1e-12, "{eye:?}");
        }
    }

    #[test]
    fn bad_parameters_are_named() {
        for (query, needle) in [
            (format!("{VIEW}&frobnicate=1"), "frobnicate"),
            (format!("{VIEW}&lod=12&lod=42"), "`lod`"),
            (format!("{VIEW}&depth=npy"), "`depth`"),
            (
                "eye=0,0&target=0,0,0&yfov_deg=40&width=8&height=8".to_owned(),
                "`eye`",
            ),
            (
                "eye=0,0,3&target=0,0,0&yfov_deg=NaN&width=8&height=8".to_owned(),
                "`yfov_deg`",
            ),
            (
                "eye=0,0,3&target=0,0,0&yfov_deg=40&width=-1&height=8".to_owned(),
                "`width`",
            ),
            (
                "eye=0,0,3&target=0,0,0&yfov_deg=40&width=8".to_owned(),
                "`height`",
            ),
            (format!("{VIEW}&step=1e999"), "`step`"),
            (format!("{VIEW}&background=1,2,3"), "`background`"),
            (format!("{VIEW}&background=1,2,3,256"), "`background`"),
            (format!("{VIEW}&quality=0"), "quality"),
            (format!("{VIEW}&az=10"), "`az`"),
            (
                "az=1&el=2&dist=0&target=0,0,0&yfov_deg=40&width=8&height=8".to_owned(),
                "`dist`",
            ),
            (
                "az=1&el=2&target=0,0,0&yfov_deg=40&width=8&height=8".to_owned(),
                "`dist`",
            ),
        ] {
            let text = message(&query);
            assert!(text.contains(needle), "{query}: {text}");
        }
    }
}
