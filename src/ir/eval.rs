//! Compile-time evaluation of checked node bodies, used by constant folding. It evaluates a
//! node whose inputs are all constant; anything that is not a compile-time constant (a shading
//! global, a texture, a closure, a loop that runs too long) makes it give up, never guess.

use crate::front::ast::BinaryOp;
use crate::front::hir::{Expr, ExprKind, Function, Place, Stmt, UnaryOp};
use crate::front::intrinsics::Intrinsic;
use crate::front::library::Library;
use crate::front::types::{Type, Value};
use crate::runtime::{math, noise};

/// Deepest nesting of statements and expressions in one entry function once node bodies and
/// user functions are inlined into one another: four functions each nested to the parser's
/// [`MAX_NESTING`](crate::front::parser::MAX_NESTING). Lowering and constant folding recurse
/// this deep at most, which the compiler stack ([`crate::stack`]) holds with room to spare;
/// past it lowering reports the inlining chain.
pub const MAX_INLINED_NESTING: u32 = 4 * crate::front::parser::MAX_NESTING;

/// Loop iterations one folding attempt may spend before it gives up.
const FOLD_BUDGET: u32 = 100_000;

/// Expressions and statements one folding attempt may evaluate before it gives up: folding
/// `f24(1.0)`, where each of 24 functions calls the one before twice, would otherwise take
/// 2²⁴ calls. Far above any built-in node's needs (fbm: a few thousand).
const FOLD_STEPS: u32 = 1 << 20;

/// Why evaluation stopped.
enum Stop {
    /// Not a compile-time constant: leave the node for run time.
    NotConstant,
}

enum Flow {
    Normal,
    Break,
    Continue,
    Return(Option<Value>),
}

struct Frame {
    locals: Vec<Option<Value>>,
}

struct Evaluator<'a> {
    lib: &'a Library,
    budget: u32,
    /// What is left of [`FOLD_STEPS`].
    steps: u32,
    /// Call depth; recursion is a reported error, but folding must not overflow the stack
    /// while the rest of a broken file is still being checked.
    depth: u32,
    /// Statement and expression nesting across inlined calls; past
    /// [`MAX_INLINED_NESTING`] folding gives up (lowering reports it).
    nesting: u32,
}

/// Deepest user-function nesting folding follows.
const MAX_CALL_DEPTH: u32 = 64;

/// Evaluates a node type with the given input values (`None`: use the parameter's default).
/// Returns the value of every parameter after the body ran (outputs included), or `None` if
/// the result is not a compile-time constant.
pub fn eval_node(lib: &Library, func: &Function, inputs: &[Option<Value>]) -> Option<Vec<Value>> {
    crate::stack::on_compiler_stack(|| eval_node_here(lib, func, inputs))
}

fn eval_node_here(lib: &Library, func: &Function, inputs: &[Option<Value>]) -> Option<Vec<Value>> {
    let mut ev = Evaluator { lib, budget: FOLD_BUDGET, steps: FOLD_STEPS, depth: 0, nesting: 0 };
    let mut frame = Frame { locals: vec![None; func.locals.len()] };
    for (i, param) in func.params.iter().enumerate() {
        let value = match inputs.get(i).cloned().flatten() {
            Some(v) => Some(v),
            None => match &param.default {
                Some(d) => Some(ev.expr(d, &mut frame).ok()?),
                None => Value::zero(param.ty),
            },
        };
        frame.locals[i] = value;
    }
    match ev.block(&func.body, &mut frame) {
        Ok(_) => {}
        Err(Stop::NotConstant) => return None,
    }
    frame.locals[..func.params.len()].iter().cloned().collect()
}

impl Evaluator<'_> {
    fn block(&mut self, stmts: &[Stmt], frame: &mut Frame) -> Result<Flow, Stop> {
        for stmt in stmts {
            match self.stmt(stmt, frame)? {
                Flow::Normal => {}
                other => return Ok(other),
            }
        }
        Ok(Flow::Normal)
    }

    /// Counts one step and one level of nesting, or gives up past the budgets.
    fn enter(&mut self) -> Result<(), Stop> {
        self.steps = self.steps.checked_sub(1).ok_or(Stop::NotConstant)?;
        if self.nesting >= MAX_INLINED_NESTING {
            return Err(Stop::NotConstant);
        }
        self.nesting += 1;
        Ok(())
    }

    fn stmt(&mut self, stmt: &Stmt, frame: &mut Frame) -> Result<Flow, Stop> {
        self.enter()?;
        let flow = self.stmt_here(stmt, frame);
        self.nesting -= 1;
        flow
    }

    fn stmt_here(&mut self, stmt: &Stmt, frame: &mut Frame) -> Result<Flow, Stop> {
        match stmt {
            Stmt::Assign(place, value) => {
                let v = self.expr(value, frame)?;
                self.store(place, v, frame)?;
            }
            Stmt::Eval(e) => {
                self.expr(e, frame)?;
            }
            Stmt::If(cond, then, otherwise) => {
                let c = truthy(&self.expr(cond, frame)?);
                return self.block(if c { then } else { otherwise }, frame);
            }
            Stmt::Loop { cond, body, step, .. } => loop {
                if let Some(cond) = cond
                    && !truthy(&self.expr(cond, frame)?)
                {
                    break;
                }
                self.budget = self.budget.checked_sub(1).ok_or(Stop::NotConstant)?;
                match self.block(body, frame)? {
                    Flow::Break => break,
                    Flow::Return(v) => return Ok(Flow::Return(v)),
                    Flow::Normal | Flow::Continue => {}
                }
                self.block(step, frame)?;
            },
            Stmt::Break => return Ok(Flow::Break),
            Stmt::Continue => return Ok(Flow::Continue),
            Stmt::Return(v) => {
                let v = match v {
                    Some(e) => Some(self.expr(e, frame)?),
                    None => None,
                };
                return Ok(Flow::Return(v));
            }
        }
        Ok(Flow::Normal)
    }

    fn store(&mut self, place: &Place, value: Value, frame: &mut Frame) -> Result<(), Stop> {
        let element = match &place.element {
            Some(e) => Some(as_int(&self.expr(e, frame)?)?),
            None => None,
        };
        let component = match &place.component {
            Some(e) => Some(as_int(&self.expr(e, frame)?)?),
            None => None,
        };
        let slot = frame.locals[place.local.0 as usize].as_mut().ok_or(Stop::NotConstant)?;
        let target = match (element, slot) {
            (Some(i), Value::Array(items)) => items.get_mut(usize::try_from(i).map_err(|_| Stop::NotConstant)?),
            (None, v) => Some(v),
            _ => None,
        }
        .ok_or(Stop::NotConstant)?;
        match (component, target) {
            (None, t) => *t = value,
            (Some(c), Value::Triple(t)) => {
                let c = usize::try_from(c).ok().filter(|c| *c < 3).ok_or(Stop::NotConstant)?;
                t[c] = value.as_f32().ok_or(Stop::NotConstant)?;
            }
            _ => return Err(Stop::NotConstant),
        }
        Ok(())
    }

    fn expr(&mut self, expr: &Expr, frame: &mut Frame) -> Result<Value, Stop> {
        self.enter()?;
        let value = self.expr_here(expr, frame);
        self.nesting -= 1;
        value
    }

    /// Evaluates a chain of binary operators and conversions along its left spine in a loop
    /// (see `check::binary_chain`): innermost first, each step applied to the value so far.
    fn spine(&mut self, expr: &Expr, frame: &mut Frame) -> Result<Value, Stop> {
        let (spine, leaf) = expr.left_spine();
        let mut acc = self.expr(leaf, frame)?;
        for node in spine.into_iter().rev() {
            self.steps = self.steps.checked_sub(1).ok_or(Stop::NotConstant)?;
            acc = match &node.kind {
                ExprKind::Convert(a) => convert(acc, a.ty, node.ty),
                // Logic short-circuits.
                ExprKind::Binary(op @ (BinaryOp::And | BinaryOp::Or), _, b) => {
                    let l = truthy(&acc);
                    let r = if (*op == BinaryOp::And) == l { truthy(&self.expr(b, frame)?) } else { l };
                    Value::Int(r as i32)
                }
                ExprKind::Binary(op, _, b) => {
                    let r = self.expr(b, frame)?;
                    binary(*op, acc, r)?
                }
                _ => return Err(Stop::NotConstant),
            };
        }
        Ok(acc)
    }

    fn expr_here(&mut self, expr: &Expr, frame: &mut Frame) -> Result<Value, Stop> {
        Ok(match &expr.kind {
            ExprKind::Const(v) => v.clone(),
            ExprKind::Local(id) => frame.locals[id.0 as usize].clone().ok_or(Stop::NotConstant)?,
            ExprKind::Global(_) => return Err(Stop::NotConstant),
            ExprKind::Unary(op, a) => {
                let a = self.expr(a, frame)?;
                match (op, a) {
                    (UnaryOp::Neg, Value::Int(i)) => Value::Int(i.wrapping_neg()),
                    (UnaryOp::Neg, Value::Float(x)) => Value::Float(-x),
                    (UnaryOp::Neg, Value::Triple(t)) => Value::Triple(t.map(|c| -c)),
                    (UnaryOp::Not, v) => Value::Int(!truthy(&v) as i32),
                    _ => return Err(Stop::NotConstant),
                }
            }
            ExprKind::Binary(..) | ExprKind::Convert(_) => self.spine(expr, frame)?,
            ExprKind::Select(c, a, b) => {
                if truthy(&self.expr(c, frame)?) {
                    self.expr(a, frame)?
                } else {
                    self.expr(b, frame)?
                }
            }
            ExprKind::Construct(parts) => {
                let mut t = [0.0; 3];
                for (slot, part) in t.iter_mut().zip(parts.iter()) {
                    *slot = self.expr(part, frame)?.as_f32().ok_or(Stop::NotConstant)?;
                }
                Value::Triple(t)
            }
            ExprKind::Component(a, c) => match self.expr(a, frame)? {
                Value::Triple(t) => Value::Float(t[*c as usize]),
                _ => return Err(Stop::NotConstant),
            },
            ExprKind::Index(a, i) => {
                let base = self.expr(a, frame)?;
                let i = usize::try_from(as_int(&self.expr(i, frame)?)?).map_err(|_| Stop::NotConstant)?;
                match base {
                    Value::Array(items) => items.get(i).cloned().ok_or(Stop::NotConstant)?,
                    Value::Triple(t) => Value::Float(*t.get(i).ok_or(Stop::NotConstant)?),
                    _ => return Err(Stop::NotConstant),
                }
            }
            ExprKind::Array(items) => {
                let mut out = Vec::with_capacity(items.len());
                for item in items {
                    out.push(self.expr(item, frame)?);
                }
                Value::Array(out)
            }
            ExprKind::Intrinsic(intrinsic, args) => {
                let mut values = Vec::with_capacity(args.len());
                for a in args {
                    values.push(self.expr(a, frame)?);
                }
                intrinsic_value(*intrinsic, &values)?
            }
            ExprKind::Call(id, args) => {
                let func = self.lib.function(*id);
                if self.depth >= MAX_CALL_DEPTH {
                    return Err(Stop::NotConstant);
                }
                let mut callee = Frame { locals: vec![None; func.locals.len()] };
                for (i, a) in args.iter().enumerate() {
                    callee.locals[i] = Some(self.expr(a, frame)?);
                }
                self.depth += 1;
                let flow = self.block(&func.body, &mut callee);
                self.depth -= 1;
                match flow? {
                    Flow::Return(Some(v)) => v,
                    _ => Value::zero(func.ret).ok_or(Stop::NotConstant)?,
                }
            }
        })
    }
}

fn truthy(v: &Value) -> bool {
    match v {
        Value::Int(i) => *i != 0,
        Value::Float(x) => *x != 0.0,
        _ => false,
    }
}

fn as_int(v: &Value) -> Result<i32, Stop> {
    match v {
        Value::Int(i) => Ok(*i),
        _ => Err(Stop::NotConstant),
    }
}

fn convert(v: Value, from: Type, to: Type) -> Value {
    match (v, to) {
        (Value::Float(x), t) if t == Type::INT => Value::Int(math::float_to_int(x)),
        (v, _) => v.convert(from, to),
    }
}

/// Applies `f` per component to floats and triples.
fn map1(v: &Value, f: impl Fn(f32) -> f32) -> Result<Value, Stop> {
    match v {
        Value::Float(x) => Ok(Value::Float(f(*x))),
        Value::Triple(t) => Ok(Value::Triple(t.map(f))),
        _ => Err(Stop::NotConstant),
    }
}

fn components(v: &Value) -> Result<([f32; 3], bool), Stop> {
    match v {
        Value::Float(x) => Ok(([*x; 3], false)),
        Value::Triple(t) => Ok((*t, true)),
        Value::Int(i) => Ok(([*i as f32; 3], false)),
        _ => Err(Stop::NotConstant),
    }
}

fn map_n(args: &[Value], f: impl Fn(&[f32]) -> f32) -> Result<Value, Stop> {
    let mut triple = false;
    let mut parts = Vec::with_capacity(args.len());
    for a in args {
        let (c, t) = components(a)?;
        triple |= t;
        parts.push(c);
    }
    let lane = |k: usize| f(&parts.iter().map(|p| p[k]).collect::<Vec<_>>());
    Ok(if triple { Value::Triple([lane(0), lane(1), lane(2)]) } else { Value::Float(lane(0)) })
}

fn binary(op: BinaryOp, l: Value, r: Value) -> Result<Value, Stop> {
    use BinaryOp::*;
    Ok(match (l, r) {
        (Value::Int(a), Value::Int(b)) => Value::Int(match op {
            Add => a.wrapping_add(b),
            Sub => a.wrapping_sub(b),
            Mul => a.wrapping_mul(b),
            Div => math::int_div(a, b),
            Rem => math::int_rem(a, b),
            Eq => (a == b) as i32,
            Ne => (a != b) as i32,
            Lt => (a < b) as i32,
            Le => (a <= b) as i32,
            Gt => (a > b) as i32,
            Ge => (a >= b) as i32,
            And | Or => unreachable!("logic is short-circuited by the caller"),
        }),
        (Value::Str(a), Value::Str(b)) => Value::Int(match op {
            Eq => (a == b) as i32,
            Ne => (a != b) as i32,
            _ => return Err(Stop::NotConstant),
        }),
        (l, r) => {
            let (a, _) = components(&l)?;
            let (b, triple) = components(&r)?;
            let cmp = |f: fn(f32, f32) -> bool| {
                let n = if triple { 3 } else { 1 };
                (0..n).all(|k| f(a[k], b[k]))
            };
            match op {
                Eq => return Ok(Value::Int(cmp(|x, y| x == y) as i32)),
                Ne => return Ok(Value::Int(!cmp(|x, y| x == y) as i32)),
                Lt => return Ok(Value::Int(cmp(|x, y| x < y) as i32)),
                Le => return Ok(Value::Int(cmp(|x, y| x <= y) as i32)),
                Gt => return Ok(Value::Int(cmp(|x, y| x > y) as i32)),
                Ge => return Ok(Value::Int(cmp(|x, y| x >= y) as i32)),
                _ => {}
            }
            let f: fn(f32, f32) -> f32 = match op {
                Add => |x, y| x + y,
                Sub => |x, y| x - y,
                Mul => |x, y| x * y,
                Div => |x, y| x / y,
                _ => math::float_mod,
            };
            map_n(&[l, r], |p| f(p[0], p[1]))?
        }
    })
}

fn triple(v: &Value) -> Result<[f32; 3], Stop> {
    match v {
        Value::Triple(t) => Ok(*t),
        _ => Err(Stop::NotConstant),
    }
}

/// Evaluates an intrinsic on constant arguments (already converted to its parameter types).
fn intrinsic_value(i: Intrinsic, a: &[Value]) -> Result<Value, Stop> {
    use Intrinsic::*;
    let v3 = |k: usize| triple(&a[k]);
    Ok(match i {
        Sin => map1(&a[0], f32::sin)?,
        Cos => map1(&a[0], f32::cos)?,
        Tan => map1(&a[0], f32::tan)?,
        Asin => map1(&a[0], f32::asin)?,
        Acos => map1(&a[0], f32::acos)?,
        Atan => map1(&a[0], f32::atan)?,
        Sqrt => map1(&a[0], f32::sqrt)?,
        InverseSqrt => map1(&a[0], math::inversesqrt)?,
        Exp => map1(&a[0], f32::exp)?,
        Exp2 => map1(&a[0], f32::exp2)?,
        Log => map1(&a[0], f32::ln)?,
        Log2 => map1(&a[0], f32::log2)?,
        Abs => map1(&a[0], f32::abs)?,
        Floor => map1(&a[0], f32::floor)?,
        Ceil => map1(&a[0], f32::ceil)?,
        Round => map1(&a[0], math::round)?,
        Fract => map1(&a[0], math::fract)?,
        Sign => map1(&a[0], math::sign)?,
        Radians => map1(&a[0], f32::to_radians)?,
        Degrees => map1(&a[0], f32::to_degrees)?,
        Pow => map_n(a, |p| p[0].powf(p[1]))?,
        Atan2 => map_n(a, |p| p[0].atan2(p[1]))?,
        Min => map_n(a, |p| math::min(p[0], p[1]))?,
        Max => map_n(a, |p| math::max(p[0], p[1]))?,
        Mod => map_n(a, |p| math::float_mod(p[0], p[1]))?,
        Step => map_n(a, |p| math::step(p[0], p[1]))?,
        Clamp => map_n(a, |p| math::clamp(p[0], p[1], p[2]))?,
        Smoothstep => map_n(a, |p| math::smoothstep(p[0], p[1], p[2]))?,
        Mix => map_n(a, |p| p[0] + (p[1] - p[0]) * p[2])?,
        Dot => {
            let (x, y) = (v3(0)?, v3(1)?);
            Value::Float(x[0] * y[0] + x[1] * y[1] + x[2] * y[2])
        }
        Cross => {
            let (x, y) = (v3(0)?, v3(1)?);
            Value::Triple([x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]])
        }
        Length => {
            let x = v3(0)?;
            Value::Float((x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt())
        }
        Normalize => {
            let x = v3(0)?;
            let len = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
            Value::Triple(if len > 0.0 { x.map(|c| c / len) } else { [0.0; 3] })
        }
        Distance => {
            let (x, y) = (v3(0)?, v3(1)?);
            let d = [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
            Value::Float((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt())
        }
        Luminance => {
            let c = v3(0)?;
            Value::Float(math::luminance(c[0], c[1], c[2]))
        }
        Noise => {
            let p = v3(0)?;
            Value::Float(noise::noise3(p[0], p[1], p[2]))
        }
        Snoise => {
            let p = v3(0)?;
            Value::Float(noise::snoise3(p[0], p[1], p[2]))
        }
        Cellnoise => {
            let p = v3(0)?;
            Value::Float(noise::cellnoise3(p[0], p[1], p[2]))
        }
        Cellular => {
            let p = v3(0)?;
            Value::Float(noise::cellular3(p[0], p[1], p[2]))
        }
        Texture
        | TextureChannel
        | Primvar
        | PrimvarFloat
        | PrimvarVector
        | PrimvarAlpha
        | DiffuseBsdf
        | GlossyBsdf
        | MetalBsdf
        | GlassBsdf
        | ConductorBsdf
        | DielectricBsdf
        | GeneralizedSchlickBsdf
        | OrenNayarDiffuseBsdf
        | BurleyDiffuseBsdf
        | SheenBsdf
        | TranslucentBsdf
        | Layer
        | WithNormal
        | WithThinFilm
        | WithDarkening
        | WithAnisotropy
        | WithThinWalled => return Err(Stop::NotConstant),
    })
}
