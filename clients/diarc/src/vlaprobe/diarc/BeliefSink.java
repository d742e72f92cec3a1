package vlaprobe.diarc;

import java.util.List;
import java.util.Set;

/**
 * THE adapter point to DIARC: where the per-step belief differences go.
 *
 * <p>A DIARC component implements this with its belief interface, one call per step and set, e.g.
 *
 * <pre>
 *   public void assertBeliefs(Set&lt;String&gt; terms) {
 *     Set&lt;Term&gt; ts = terms.stream().map(Factory::createPredicate).collect(Collectors.toSet());
 *     TRADE.getAvailableService(new TRADEServiceConstraints().name("assertBeliefs").argTypes(Set.class, MemoryLevel.class))
 *          .call(void.class, ts, MemoryLevel.WORKING);
 *   }
 * </pre>
 *
 * and the same for {@code retractBeliefs}. Terms arrive in DIARC's spelling, e.g. {@code left_of(akita_black_bowl_1,plate_1)}.
 */
public interface BeliefSink {
    /** Terms newly believed at this step (one call per step; never called with an empty set). */
    void assertBeliefs(Set<String> terms);

    /** Terms no longer believed at this step (one call per step; never called with an empty set). */
    void retractBeliefs(Set<String> terms);

    /** The consistency violations active at this step (rule id and message each); called every step. */
    default void violations(int t, List<String> active) {}

    /**
     * The cognition's alarm fired at step t ({@code serve --takeover alarm}): its kind ("stall", "regression",
     * "dropped", "violation"), its reason, and the rules and atoms that drove it; the expert acts from t + 1.
     */
    default void alarm(int t, String kind, String reason, List<String> rules, List<String> atoms) {}

    /**
     * Control changed hands at step t: {@code toExpert} true when the scripted expert executes this step's action
     * (a takeover begins, {@code reason} says why), false when the policy acts again.
     */
    default void handover(int t, boolean toExpert, String reason) {}

    /** A new episode begins: a DIARC component may clear its WORKING memory here. */
    default void episodeStart(String episodeId, String instruction) {}

    /**
     * The episode's atoms (object head, then action head), called after {@link #episodeStart}: those defined in it
     * and those undefined (over an object absent from the task, in a suite whose tasks have different objects;
     * {@code episode_start.defined}, protocol 3). An undefined atom is neither true nor false: no belief over it
     * is ever asserted.
     */
    default void atoms(List<String> defined, List<String> undefined) {}

    /** The episode is over. */
    default void episodeEnd(String episodeId, boolean success, int steps) {}
}
