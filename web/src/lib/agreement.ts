/** Agreement of the probes' predictions with the world's truth, per atom and per step. */

export type Agreement = "agree" | "disagree" | "unknown";

/** Per atom: agree/disagree with truth; "unknown" where no truth is streamed or the atom is not probed. */
export function atomAgreement(
  predicted: readonly number[],
  truth: readonly number[] | null,
  probed: readonly boolean[],
): Agreement[] {
  return predicted.map((p, i) => {
    if (!truth || !probed[i] || truth[i] === undefined) return "unknown";
    return p === truth[i] ? "agree" : "disagree";
  });
}

/** Share of probed atoms whose prediction matches truth, in percent; null without truth or probed atoms. */
export function agreementPercent(
  predicted: readonly number[],
  truth: readonly number[] | null,
  probed: readonly boolean[],
): number | null {
  if (!truth) return null;
  let n = 0;
  let same = 0;
  for (let i = 0; i < predicted.length; i++) {
    if (!probed[i] || truth[i] === undefined) continue;
    n++;
    if (predicted[i] === truth[i]) same++;
  }
  return n === 0 ? null : (100 * same) / n;
}
