% vlaprobe's shipped consistency rules in DIARC's belief-rule syntax (tuProlog: ':-', 'not(...)', '\=').
% The same rules as consistency.lp (clingo); tests/cognition checks that both flag the same violations.
%
% Beliefs are asserted per step as DIARC terms: left_of(A,B), behind(A,B), on(A,B), on_table(A), inside(A,C),
% open(C), turned_on(K), grasped(A), should_move_towards(A), ...; with them, from the belief history,
% prev(B) (held at the previous step), ever(B) (held at some step so far) and recent(B) (held within the
% last W steps), and the task's goal(Pick,Place). A violation is violation(Id, Key), with the beliefs in Key
% and any involves(Id, Key, Belief); message(Id, Text) is the rule's one-line message.
% Register for notification on violation(Id, Key) to be told when one appears or disappears.
% Messages are double-quoted: DIARC's init-file loader strips whitespace outside double quotes.

% --- support ---------------------------------------------------------------------------------------------
message(on_and_inside, "an object is both on something and inside a drawer").
violation(on_and_inside, (on(X,Y), inside(X,C))) :- on(X,Y), inside(X,C), container(C), not(part_of(C,Y)).

message(on_two_supports, "an object is on two things at once").
violation(on_two_supports, (on(X,Y), on(X,Z))) :- on(X,Y), on(X,Z), Y @< Z.

message(on_mutual, "two objects are on each other").
violation(on_mutual, (on(X,Y), on(Y,X))) :- on(X,Y), on(Y,X), X @< Y.

message(on_and_on_table, "an object is both on another object and on the table").
violation(on_and_on_table, (on(X,Y), on_table(X))) :- on(X,Y), on_table(X).

% --- spatial relations -----------------------------------------------------------------------------------
message(opposite_sides, "an object is on both sides of another").
violation(opposite_sides, (left_of(X,Y), right_of(X,Y))) :- left_of(X,Y), right_of(X,Y).
violation(opposite_sides, (behind(X,Y), in_front_of(X,Y))) :- behind(X,Y), in_front_of(X,Y).

message(left_right_converse, "left-of and right-of disagree: one holds without its converse").
violation(left_right_converse, (left_of(X,Y), right_of(Y,X))) :- left_of(X,Y), not(right_of(Y,X)).
violation(left_right_converse, (left_of(X,Y), right_of(Y,X))) :- right_of(Y,X), not(left_of(X,Y)).

message(behind_front_converse, "behind and in-front-of disagree: one holds without its converse").
violation(behind_front_converse, (behind(X,Y), in_front_of(Y,X))) :- behind(X,Y), not(in_front_of(Y,X)).
violation(behind_front_converse, (behind(X,Y), in_front_of(Y,X))) :- in_front_of(Y,X), not(behind(X,Y)).

% An order relation must not have a cycle. edge(R,X,Y,B): belief B puts X before Y in order R, and nothing
% puts Y before X (such two-way pairs are reported by opposite_sides or a converse rule already).
edge(left_of, X, Y, left_of(X,Y)) :- left_of(X,Y), not(left_of(Y,X)).
edge(right_of, X, Y, right_of(X,Y)) :- right_of(X,Y), not(right_of(Y,X)).
edge(behind, X, Y, behind(X,Y)) :- behind(X,Y), not(behind(Y,X)).
edge(in_front_of, X, Y, in_front_of(X,Y)) :- in_front_of(X,Y), not(in_front_of(Y,X)).
order(left_of). order(right_of). order(behind). order(in_front_of).
% reachable(R, X, S): S lists every object reachable from X along R's edges (breadth first, each once)
reachable(R, X, S) :- grow(R, [X], [], S).
grow(_, [], S, S).
grow(R, [N|Queue], Seen, S) :-
    findall(Z, (edge(R, N, Z, _), not(member(Z, Seen))), New),
    append(Queue, New, Queue1), append(Seen, New, Seen1), grow(R, Queue1, Seen1, S).
cyclic(R, X, Y) :- reachable(R, X, S), member(Y, S), reachable(R, Y, S2), member(X, S2).
% one violation per cycle (strongly connected part), named by its smallest object M
message(order_cycle, "a spatial order goes round in a cycle").
violation(order_cycle, (R,M)) :- order(R), object(M), cyclic(R, M, M), not(cyclic_below(R, M)).
cyclic_below(R, M) :- cyclic(R, M, Z), Z @< M.
involves(order_cycle, (R,M), B) :- violation(order_cycle, (R,M)), edge(R, X, Y, B), cyclic(R, M, X), cyclic(R, M, Y).

% --- action state ----------------------------------------------------------------------------------------
message(grasped_many, "more than one object is grasped").
violation(grasped_many, (grasped(X), grasped(Y))) :- grasped(X), grasped(Y), X @< Y.

message(towards_not_one, "not exactly one object to move towards while the goal does not hold (nor held recently)").
violation(towards_not_one, on(X,Y)) :-
    goal(X, Y), not(on(X, Y)), not(recent(on(X, Y))), findall(O, should_move_towards(O), L), length(L, N), N \= 1.
involves(towards_not_one, G, should_move_towards(O)) :- violation(towards_not_one, G), should_move_towards(O).

% --- over the history ------------------------------------------------------------------------------------
% (on its place only: while being picked, the object may lose and regain contact with what it stood on)
message(on_while_grasped, "the task's object is on its place while still grasped").
violation(on_while_grasped, (on(X,Y), grasped(X))) :- goal(X, Y), on(X, Y), grasped(X).

message(placed_without_grasp, "the task's object came to rest on its place without having been grasped").
violation(placed_without_grasp, (on(X,Y), grasped(X))) :-
    goal(X, Y), on(X, Y), not(prev(on(X, Y))), not(ever(grasped(X))).

message(inside_changed_closed, "an object went into or out of a drawer that was not open recently").
violation(inside_changed_closed, (inside(X,C), open(C))) :-
    inside(X, C), container(C), not(prev(inside(X, C))), not(recent(open(C))).
violation(inside_changed_closed, (inside(X,C), open(C))) :-
    prev(inside(X, C)), container(C), not(inside(X, C)), not(recent(open(C))).
